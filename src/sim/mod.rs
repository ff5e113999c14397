//! Sensor simulator: IMU and GNSS error models, scenes, presets, byte-stream serving.
pub mod motion;
