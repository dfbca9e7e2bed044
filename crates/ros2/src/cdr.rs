//! ROS 2 CDR encoding of a message: the 4-byte encapsulation header
//! `00 01 00 00` (CDR, little-endian), then the plain CDR of the serde
//! struct (`cdr-encoding`, the serializer `ros2-client` uses), aligned from
//! the byte after the encapsulation header, as ROS 2 writes it on DDS, into
//! MCAP (`insuwb-mcap`) and on Zenoh (`insuwb-zenoh`, rmw_zenoh's payload).
//! [`decode`] reads it back, in either byte order.
//!
//! ```
//! use insuwb_ros2::cdr::{decode, encode, CDR_LE};
//! use insuwb_ros2::msgs::{Header, Time};
//! let h = Header { stamp: Time { sec: 5, nanosec: 1 }, frame_id: "map".into() };
//! let bytes = encode(&h, "std_msgs/msg/Header").unwrap();
//! assert_eq!(bytes[..4], CDR_LE);
//! assert_eq!(decode::<Header>(&bytes, "std_msgs/msg/Header").unwrap(), h);
//! ```

use byteorder::{BigEndian, LittleEndian};
use serde::de::DeserializeOwned;
use serde::Serialize;

/// The encapsulation header of little-endian plain CDR (`CDR_LE`).
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// The encapsulation header of big-endian plain CDR (`CDR_BE`).
pub const CDR_BE: [u8; 4] = [0x00, 0x00, 0x00, 0x00];

/// A message that CDR cannot encode.
#[derive(Debug, thiserror::Error)]
#[error("EncodeError: cannot CDR-encode a {type_name}: {message}")]
pub struct EncodeError {
    /// The message type.
    pub type_name: String,
    /// The serializer's error.
    pub message: String,
}

/// Bytes that are not the CDR of the message type asked for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Fewer than 4 bytes, or an encapsulation header other than plain CDR
    /// in either byte order.
    #[error("DecodeError::Encapsulation: {type_name}: not plain CDR (header {header:02x?})")]
    Encapsulation {
        /// The message type.
        type_name: String,
        /// The first bytes (up to 4).
        header: Vec<u8>,
    },
    /// The body does not hold the type (too short, a bad string or length).
    #[error("DecodeError::Body: {type_name}: {message}")]
    Body {
        /// The message type.
        type_name: String,
        /// The deserializer's error.
        message: String,
    },
}

/// `msg` as the data of a ROS 2 message: [`CDR_LE`], then its CDR bytes.
///
/// # Errors
/// [`EncodeError`] when the serializer refuses the value (the messages of
/// [`crate::msgs`] and `insuwb-mcap` always encode).
pub fn encode<M: Serialize>(msg: &M, type_name: &str) -> Result<Vec<u8>, EncodeError> {
    let body = cdr_encoding::to_vec::<M, LittleEndian>(msg).map_err(|e| EncodeError {
        type_name: type_name.to_owned(),
        message: e.to_string(),
    })?;
    let mut out = Vec::with_capacity(CDR_LE.len() + body.len());
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&body);
    Ok(out)
}

/// The message of `bytes` ([`CDR_LE`] or [`CDR_BE`], then its CDR);
/// bytes after the message (alignment padding) are ignored.
///
/// # Errors
/// [`DecodeError`] for another encapsulation or a body that does not hold
/// the type.
pub fn decode<M: DeserializeOwned>(bytes: &[u8], type_name: &str) -> Result<M, DecodeError> {
    let (header, body) = bytes.split_at(bytes.len().min(4));
    let body_err = |e: cdr_encoding::Error| DecodeError::Body {
        type_name: type_name.to_owned(),
        message: e.to_string(),
    };
    if header == CDR_LE {
        cdr_encoding::from_bytes::<M, LittleEndian>(body)
            .map(|(m, _)| m)
            .map_err(body_err)
    } else if header == CDR_BE {
        cdr_encoding::from_bytes::<M, BigEndian>(body)
            .map(|(m, _)| m)
            .map_err(body_err)
    } else {
        Err(DecodeError::Encapsulation {
            type_name: type_name.to_owned(),
            header: header.to_vec(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Odometry, Time};

    #[test]
    fn a_header_encodes_as_ros2_writes_it() {
        let h = Header {
            stamp: Time { sec: 5, nanosec: 1 },
            frame_id: "map".into(),
        };
        let bytes = encode(&h, "std_msgs/msg/Header").unwrap();
        #[rustfmt::skip]
        let want = [
            0x00, 0x01, 0x00, 0x00, // CDR_LE
            0x05, 0x00, 0x00, 0x00, // sec 5
            0x01, 0x00, 0x00, 0x00, // nanosec 1
            0x04, 0x00, 0x00, 0x00, // string length 4 (with the NUL)
            b'm', b'a', b'p', 0x00, // "map\0"
        ];
        assert_eq!(bytes, want);
        assert_eq!(decode::<Header>(&bytes, "std_msgs/msg/Header").unwrap(), h);
        #[rustfmt::skip]
        let be = [
            0x00, 0x00, 0x00, 0x00, // CDR_BE
            0x00, 0x00, 0x00, 0x05, // sec 5
            0x00, 0x00, 0x00, 0x01, // nanosec 1
            0x00, 0x00, 0x00, 0x04, // string length 4
            b'm', b'a', b'p', 0x00,
        ];
        assert_eq!(decode::<Header>(&be, "std_msgs/msg/Header").unwrap(), h);
    }

    #[test]
    fn eight_byte_fields_align_from_the_end_of_the_encapsulation_header() {
        // After `frame_id = "ab"` (4 + 3 bytes, ending at body offset 15)
        // the u16 aligns to 16; after the two u32 (ending at 28) the u64
        // aligns to 32.
        #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
        struct Msg {
            header: Header,
            a: u16,
            b: u16,
            c: u32,
            d: u32,
            e: u64,
        }
        let m = Msg {
            header: Header {
                stamp: Time::default(),
                frame_id: "ab".into(),
            },
            a: 1,
            b: 2,
            c: 3,
            d: 4,
            e: 5,
        };
        let bytes = encode(&m, "test/msg/Msg").unwrap();
        #[rustfmt::skip]
        let want: Vec<u8> = [
            &CDR_LE[..],
            &[0, 0, 0, 0, 0, 0, 0, 0],      // stamp 0, 0
            &[3, 0, 0, 0, b'a', b'b', 0],   // "ab\0"
            &[0],                           // pad to 16
            &[1, 0, 2, 0],                  // a, b
            &[3, 0, 0, 0, 4, 0, 0, 0],      // c, d
            &[0, 0, 0, 0],                  // pad to 32
            &[5, 0, 0, 0, 0, 0, 0, 0],      // e
        ]
        .concat();
        assert_eq!(bytes, want);
        assert_eq!(decode::<Msg>(&bytes, "test/msg/Msg").unwrap(), m);
    }

    #[test]
    fn other_encapsulations_and_short_bodies_are_refused() {
        let e = decode::<Header>(&[0x00, 0x01], "std_msgs/msg/Header").unwrap_err();
        assert!(matches!(e, DecodeError::Encapsulation { .. }), "{e}");
        // PL_CDR_LE (parameter list): not a plain message.
        let e =
            decode::<Header>(&[0x00, 0x03, 0, 0, 1, 0, 0, 0], "std_msgs/msg/Header").unwrap_err();
        assert!(
            e.to_string().starts_with("DecodeError::Encapsulation: "),
            "{e}"
        );
        let odom = encode(&Odometry::default(), "nav_msgs/msg/Odometry").unwrap();
        let e = decode::<Odometry>(&odom[..odom.len() - 9], "nav_msgs/msg/Odometry").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("DecodeError::Body: nav_msgs/msg/Odometry: "),
            "{e}"
        );
    }
}
