//! The project's log format: postcard records framed with length and CRC-32, segment files, torn-tail-tolerant reader.
#![warn(missing_docs)]
