//! Parameter fitting from calibration data (paper section 4).
