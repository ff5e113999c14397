//! Strapdown INS, error-state Kalman filter, replay and sensor-grade studies.
