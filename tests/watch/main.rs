//! watch integration tests, one binary: the incremental Allan state against a full
//! recomputation, the follower on a session growing under it, the HTTP server's security
//! rules, the command line, and a real headless Chromium loading the live page.

mod browser;
mod cli;
use imulab_test_support::live_session as common;
mod follow;
mod incremental;
mod security;
