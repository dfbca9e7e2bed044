//! Evaluation: metrics against ground truth (RMSE, ranges, NEES, NIS), the in-process runner and plots.
#![warn(missing_docs)]
