//! UTIL anchor survey files: `anN_p,x,y,z` rows giving the position of
//! anchor `N` (0-7) in metres, in the Vicon frame (x east, y north, z up).
//!
//! `anN_quat` rows (anchor orientations), blank lines and `#` comments are
//! ignored; anything else is an error naming the file and line.

use thiserror::Error;

/// Number of anchor ids (0 to 7) in the UTIL dataset.
pub const MAX_ANCHORS: usize = 8;

/// Longest line quoted back in an error message.
const MAX_QUOTED: usize = 80;

/// Why an anchor file could not be read. Every variant names the file
/// (`origin`) and, where it applies, the 1-based line number.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AnchorError {
    /// A line is not an `anN_p,x,y,z` or `anN_quat,...` row.
    #[error("{origin}:{line}: expected `anN_p,x,y,z`, got {text:?}")]
    MalformedRow {
        /// File the text came from.
        origin: String,
        /// 1-based line number.
        line: usize,
        /// The line (first 80 characters).
        text: String,
    },
    /// A coordinate is not a number.
    #[error("{origin}:{line}: coordinate {axis} is not a number: {text:?}")]
    BadNumber {
        /// File the text came from.
        origin: String,
        /// 1-based line number.
        line: usize,
        /// Which coordinate (`x`, `y`, `z`).
        axis: char,
        /// The field (first 80 characters).
        text: String,
    },
    /// A coordinate is NaN or infinite.
    #[error("{origin}:{line}: coordinate {axis} is not finite: {text:?}")]
    NonFinite {
        /// File the text came from.
        origin: String,
        /// 1-based line number.
        line: usize,
        /// Which coordinate.
        axis: char,
        /// The field (first 80 characters).
        text: String,
    },
    /// The anchor id is outside 0-7.
    #[error("{origin}:{line}: anchor id {id} is out of range 0-7")]
    IdOutOfRange {
        /// File the text came from.
        origin: String,
        /// 1-based line number.
        line: usize,
        /// The id found.
        id: u64,
    },
    /// The same anchor id has two position rows.
    #[error("{origin}:{line}: anchor {id} already defined on line {first_line}")]
    Duplicate {
        /// File the text came from.
        origin: String,
        /// 1-based line number of the second row.
        line: usize,
        /// The repeated id.
        id: u32,
        /// Line of the first row.
        first_line: usize,
    },
    /// The file holds no anchor position.
    #[error("{origin}: no `anN_p` row")]
    Empty {
        /// File the text came from.
        origin: String,
    },
}

/// Surveyed anchor positions by id (0-7), ENU metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Anchors {
    /// Position and defining line per id.
    pos: [Option<([f64; 3], usize)>; MAX_ANCHORS],
    origin: String,
}

fn clip(s: &str) -> String {
    s.chars().take(MAX_QUOTED).collect()
}

impl Anchors {
    /// Parses an anchor file. `origin` names it in error messages (a path).
    ///
    /// # Errors
    /// [`AnchorError`] for a malformed row, a bad or non-finite number, an id
    /// outside 0-7, a repeated id, or a file without any position row.
    pub fn parse(text: &str, origin: &str) -> Result<Self, AnchorError> {
        let mut pos: [Option<([f64; 3], usize)>; MAX_ANCHORS] = [None; MAX_ANCHORS];
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let row = raw.trim().trim_start_matches('\u{feff}').trim();
            if row.is_empty() || row.starts_with('#') {
                continue;
            }
            let malformed = || AnchorError::MalformedRow {
                origin: origin.to_owned(),
                line,
                text: clip(row),
            };
            let mut fields = row.split(',').map(str::trim);
            let key = fields.next().unwrap_or_default();
            let Some(rest) = key.strip_prefix("an") else {
                return Err(malformed());
            };
            let (id_text, kind) = rest.split_once('_').ok_or_else(malformed)?;
            if kind == "quat" {
                continue;
            }
            if kind != "p" || id_text.is_empty() || !id_text.bytes().all(|b| b.is_ascii_digit()) {
                return Err(malformed());
            }
            let id = id_text.parse::<u64>().unwrap_or(u64::MAX);
            let slot = usize::try_from(id)
                .ok()
                .filter(|&k| k < MAX_ANCHORS)
                .ok_or_else(|| AnchorError::IdOutOfRange {
                    origin: origin.to_owned(),
                    line,
                    id,
                })?;
            let mut p = [0.0; 3];
            for (axis, out) in ['x', 'y', 'z'].into_iter().zip(p.iter_mut()) {
                let field = fields.next().ok_or_else(malformed)?;
                let v: f64 = field.parse().map_err(|_| AnchorError::BadNumber {
                    origin: origin.to_owned(),
                    line,
                    axis,
                    text: clip(field),
                })?;
                if !v.is_finite() {
                    return Err(AnchorError::NonFinite {
                        origin: origin.to_owned(),
                        line,
                        axis,
                        text: clip(field),
                    });
                }
                *out = v;
            }
            if fields.next().is_some() {
                return Err(malformed());
            }
            let entry = pos.get_mut(slot).ok_or_else(malformed)?;
            if let Some((_, first_line)) = entry {
                return Err(AnchorError::Duplicate {
                    origin: origin.to_owned(),
                    line,
                    id: slot as u32,
                    first_line: *first_line,
                });
            }
            *entry = Some((p, line));
        }
        if pos.iter().all(Option::is_none) {
            return Err(AnchorError::Empty {
                origin: origin.to_owned(),
            });
        }
        Ok(Self {
            pos,
            origin: origin.to_owned(),
        })
    }

    /// Position of anchor `id` (ENU, m), `None` when the file lacks it.
    #[must_use]
    pub fn get(&self, id: u32) -> Option<[f64; 3]> {
        let slot = usize::try_from(id).ok()?;
        self.pos.get(slot).copied().flatten().map(|(p, _)| p)
    }

    /// Ids present, ascending.
    pub fn ids(&self) -> impl Iterator<Item = u32> + '_ {
        (0u32..)
            .zip(self.pos.iter())
            .filter_map(|(id, p)| p.map(|_| id))
    }

    /// Number of anchors present.
    #[must_use]
    pub fn len(&self) -> usize {
        self.pos.iter().flatten().count()
    }

    /// Whether no anchor is present (never true for a parsed file).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The file the anchors came from, as given to [`Anchors::parse`].
    #[must_use]
    pub fn origin(&self) -> &str {
        &self.origin
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_positions_and_skips_quat_rows() {
        let text =
            "\n# survey\nan1_p,1.5,-2,3e-1\nan0_p , 0, 0 ,0\nan1_quat,1,0,0,0\n\nan7_p,-1,-2,-3\n";
        let a = Anchors::parse(text, "x.txt").unwrap();
        assert_eq!(a.len(), 3);
        assert_eq!(a.get(1), Some([1.5, -2.0, 0.3]));
        assert_eq!(a.get(0), Some([0.0; 3]));
        assert_eq!(a.get(7), Some([-1.0, -2.0, -3.0]));
        assert_eq!(a.get(2), None);
        assert_eq!(a.get(8), None);
        assert_eq!(a.get(u32::MAX), None);
        assert_eq!(a.ids().collect::<Vec<_>>(), vec![0, 1, 7]);
        assert_eq!(a.origin(), "x.txt");
    }

    #[test]
    fn errors_name_file_and_line() {
        let e = Anchors::parse("an0_p,1,2,3\nan0_p,1,2,3\n", "f.txt").unwrap_err();
        assert_eq!(
            e,
            AnchorError::Duplicate {
                origin: "f.txt".into(),
                line: 2,
                id: 0,
                first_line: 1
            }
        );
        assert_eq!(e.to_string(), "f.txt:2: anchor 0 already defined on line 1");
        let e = Anchors::parse("an0_p,1,2,3\n\nan8_p,1,2,3\n", "f.txt").unwrap_err();
        assert_eq!(
            e,
            AnchorError::IdOutOfRange {
                origin: "f.txt".into(),
                line: 3,
                id: 8
            }
        );
        let e = Anchors::parse("an2_p,1,zz,3\n", "g").unwrap_err();
        assert!(matches!(
            e,
            AnchorError::BadNumber {
                line: 1,
                axis: 'y',
                ..
            }
        ));
        let e = Anchors::parse("an2_p,1,2,nan\n", "g").unwrap_err();
        assert!(matches!(e, AnchorError::NonFinite { axis: 'z', .. }));
        for bad in [
            "an2_p,1,2\n",
            "an2_p,1,2,3,4\n",
            "anx_p,1,2,3\n",
            "an_p,1,2,3\n",
            "an2_q,1,2,3\n",
            "b2_p,1,2,3\n",
            "an2p,1,2,3\n",
        ] {
            let e = Anchors::parse(bad, "g").unwrap_err();
            assert!(
                matches!(e, AnchorError::MalformedRow { line: 1, .. }),
                "{bad}: {e:?}"
            );
        }
        assert!(matches!(
            Anchors::parse("an99999999999999999999999_p,1,2,3", "g").unwrap_err(),
            AnchorError::IdOutOfRange { .. }
        ));
        assert_eq!(
            Anchors::parse("# nothing\nan0_quat,1,0,0,0\n", "e").unwrap_err(),
            AnchorError::Empty { origin: "e".into() }
        );
    }
}
