//! Calibration procedures as pure state machines (paper section 3).
