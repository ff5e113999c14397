//! Stage timings of an analysis run, printed to stderr when the environment variable
//! `IMULAB_TIMINGS` is set (to anything): one line per stage with its wall time in ms,
//! e.g. `timings: read x 3.1 ms`. Costs one environment look-up when unset.

use std::sync::OnceLock;
use std::time::Instant;

/// Whether `IMULAB_TIMINGS` is set (looked up once).
pub fn enabled() -> bool {
    static ENABLED: OnceLock<bool> = OnceLock::new();
    *ENABLED.get_or_init(|| std::env::var_os("IMULAB_TIMINGS").is_some())
}

/// A running stage: prints its label and elapsed wall time when dropped (if enabled).
pub struct Stage {
    label: Option<String>,
    started: Instant,
}

impl Stage {
    /// Starts timing `label` (built only when timings are enabled).
    pub fn start(label: impl FnOnce() -> String) -> Stage {
        Stage {
            label: enabled().then(label),
            started: Instant::now(),
        }
    }
}

impl Drop for Stage {
    fn drop(&mut self) {
        if let Some(label) = &self.label {
            let ms = self.started.elapsed().as_secs_f64() * 1e3;
            eprintln!("timings: {label} {ms:.2} ms");
        }
    }
}
