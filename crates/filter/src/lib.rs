//! Error-state models (the paper's 14-state model and a 3D model) and the KF, SHAF, STF and IAKF filters.
#![warn(missing_docs)]
