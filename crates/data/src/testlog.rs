//! Synthetic Crazyflie logs for the unit tests.

use crate::cflog::MAGIC;

/// Builds a synthetic log: descriptors `(id, name, [spec...])`, records
/// `(id, timestamp, payload bytes)`.
pub(crate) fn build(
    version: u16,
    events: &[(u16, &str, &[&str])],
    records: &[(u16, u64, Vec<u8>)],
) -> Vec<u8> {
    let mut b = vec![MAGIC];
    b.extend_from_slice(&version.to_le_bytes());
    b.extend_from_slice(&(events.len() as u16).to_le_bytes());
    for (id, name, vars) in events {
        b.extend_from_slice(&id.to_le_bytes());
        b.extend_from_slice(name.as_bytes());
        b.push(0);
        b.extend_from_slice(&(vars.len() as u16).to_le_bytes());
        for v in *vars {
            b.extend_from_slice(v.as_bytes());
            b.push(0);
        }
    }
    for (id, ts, payload) in records {
        b.extend_from_slice(&id.to_le_bytes());
        if version == 1 {
            b.extend_from_slice(&(*ts as u32).to_le_bytes());
        } else {
            b.extend_from_slice(&ts.to_le_bytes());
        }
        b.extend_from_slice(payload);
    }
    let crc = crc32fast::hash(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    b
}
