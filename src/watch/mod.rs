//! `imulab watch`: a live page of a session while it is recorded (and the same page after).
//!
//! - [`follow`]: the session follower, reading only what was added since its last look.
//! - [`allan`]: incremental ADEV per axis (octave block sums extended as rows arrive).
//! - [`stop`]: the "when can I stop" prediction per noise term.
//! - [`trend`]: bounded time series (temperature).
//! - [`snapshot`]: what the page shows, computed from the follower.
//! - [`page`]: the HTML.
//! - [`server`]: the HTTP server (read-only, loopback by default).
//!
//! See docs/watch.md.

pub mod allan;
pub mod follow;
pub mod page;
pub mod server;
pub mod snapshot;
pub mod stop;
pub mod trend;

use crate::daemon::status::{read_status_file, StatusReport};
use crate::store::StoreError;
use follow::Follower;
use server::Rendered;
use std::path::{Path, PathBuf};
use stop::Target;

/// A followed session and what its page needs.
pub struct Watch {
    pub follower: Follower,
    pub targets: Vec<Target>,
    /// The daemon's status file to show, when it describes this session.
    status_file: Option<PathBuf>,
    /// Page refresh of the live page, s.
    pub refresh_s: f64,
    predictions: stop::Predictions,
}

impl Watch {
    /// Opens the session. `status_file`: where imulogd writes its status (default: its
    /// default place, `imulogd-status.json` beside the session directory).
    pub fn open(
        dir: &Path,
        targets: Vec<Target>,
        status_file: Option<PathBuf>,
        refresh_s: f64,
    ) -> Result<Self, StoreError> {
        let follower = Follower::open(dir)?;
        let status_file = status_file.or_else(|| {
            dir.parent()
                .map(|p| p.join("imulogd-status.json"))
                .filter(|p| p.is_file())
        });
        Ok(Watch {
            follower,
            targets,
            status_file,
            refresh_s,
            predictions: stop::Predictions::default(),
        })
    }

    /// Reads what was added since the last look.
    pub fn look(&mut self) -> Result<(), StoreError> {
        self.follower.look()
    }

    /// The daemon's status, if its file names this session.
    fn status(&self) -> Option<StatusReport> {
        let report = read_status_file(self.status_file.as_ref()?).ok()?;
        let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => false,
        };
        report
            .session_dir
            .as_deref()
            .is_some_and(|d| same(d, self.follower.dir()))
            .then_some(report)
    }

    /// The current snapshot.
    pub fn snapshot(&mut self) -> snapshot::Snapshot {
        let live = crate::store::reader::writer_is_live(self.follower.dir());
        let status = self.status();
        snapshot::snapshot(
            &self.follower,
            &mut self.predictions,
            live,
            &self.targets,
            status.as_ref(),
            crate::daemon::clock::mono_ns(),
        )
    }

    /// The live page, its fragment and the JSON state, from the current snapshot.
    pub fn render(&mut self) -> Rendered {
        let s = self.snapshot();
        Rendered {
            page: page::page(&s, Some(self.refresh_s)),
            fragment: page::fragment(&s),
            json: serde_json::to_string_pretty(&s).unwrap_or_default(),
        }
    }
}
