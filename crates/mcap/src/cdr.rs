//! ROS 2 CDR encoding of a message: the 4-byte encapsulation header
//! `00 01 00 00` (CDR, little-endian), then the plain CDR of the serde
//! struct (`cdr-encoding`, the serializer `ros2-client` uses), aligned from
//! the byte after the encapsulation header, as ROS 2 writes it on DDS and
//! into MCAP.

use byteorder::LittleEndian;
use serde::Serialize;

/// The encapsulation header of little-endian plain CDR (`CDR_LE`).
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A message that CDR cannot encode.
#[derive(Debug, thiserror::Error)]
#[error("cannot CDR-encode a {type_name}: {message}")]
pub struct EncodeError {
    /// The message type.
    pub type_name: String,
    /// The serializer's error.
    pub message: String,
}

/// `msg` as the data of a ROS 2 message: [`CDR_LE`], then its CDR bytes.
///
/// # Errors
/// [`EncodeError`] when the serializer refuses the value (the messages of
/// this crate and of `insuwb-ros2` always encode).
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::SampleHeader;
    use insuwb_ros2::msgs::{Header, Time};

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
    }

    #[test]
    fn eight_byte_fields_align_from_the_end_of_the_encapsulation_header() {
        // After `frame_id = "ab"` (4 + 3 bytes, ending at body offset 15)
        // the u16 aligns to 16; after the two u32 (ending at 28) the u64
        // aligns to 32.
        #[derive(serde::Serialize)]
        struct Msg {
            header: Header,
            sample: SampleHeader,
        }
        let m = Msg {
            header: Header {
                stamp: Time::default(),
                frame_id: "ab".into(),
            },
            sample: SampleHeader {
                layout_version: 1,
                source_id: 2,
                flags: 3,
                generation: 4,
                seq: 5,
                meas_time_ns: 6,
                pub_time_ns: 7,
            },
        };
        let bytes = encode(&m, "test/msg/Msg").unwrap();
        #[rustfmt::skip]
        let want: Vec<u8> = [
            &CDR_LE[..],
            &[0, 0, 0, 0, 0, 0, 0, 0],      // stamp 0, 0
            &[3, 0, 0, 0, b'a', b'b', 0],   // "ab\0"
            &[0],                           // pad to 16
            &[1, 0, 2, 0],                  // layout_version, source_id
            &[3, 0, 0, 0, 4, 0, 0, 0],      // flags, generation
            &[0, 0, 0, 0],                  // pad to 32
            &[5, 0, 0, 0, 0, 0, 0, 0],      // seq
            &[6, 0, 0, 0, 0, 0, 0, 0],      // meas_time_ns
            &[7, 0, 0, 0, 0, 0, 0, 0],      // pub_time_ns
        ]
        .concat();
        assert_eq!(bytes, want);
    }
}
