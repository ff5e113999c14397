//! Allan-family deviations, confidence intervals, noise-term fit and reports.
