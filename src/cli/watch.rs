//! `imulab watch SESSION`: serves a live page of a session being recorded (data health,
//! temperatures, Allan curves that converge and when the run can stop), or with `--once`
//! writes the current state as a static page / JSON. See docs/watch.md.

use crate::watch::page;
use crate::watch::server::{serve, Rendered, Shared};
use crate::watch::stop::Target;
use crate::watch::Watch;
use anyhow::{bail, Context, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab watch /data/chamber-run        then open http://127.0.0.1:8642/\n  imulab watch runs/x --target bias-instability=10% --target random-walk=3%\n  imulab watch runs/x --once --html state.html --json state.json\n  imulab watch runs/x --listen 0.0.0.0:8642   (serves every network: read-only, but anyone who reaches the port sees the session)"
)]
pub struct WatchArgs {
    /// The session directory (being recorded or finished).
    pub session: PathBuf,
    /// Address to serve on. Anything other than a loopback address exposes the page to the
    /// network (a warning is printed).
    #[arg(long, default_value = "127.0.0.1:8642")]
    pub listen: SocketAddr,
    /// A noise term's interval width to reach, TERM=WIDTH (repeatable): the page says how
    /// much more run time that takes. Terms: quantization, random-walk, bias-instability,
    /// rate-random-walk, rate-ramp.
    #[arg(long = "target", default_value = "bias-instability=10%")]
    pub targets: Vec<Target>,
    /// Seconds between looks at the session (and page refreshes).
    #[arg(long, default_value_t = 5.0)]
    pub refresh: f64,
    /// imulogd's status file (default: imulogd-status.json beside the session directory,
    /// when it describes this session).
    #[arg(long)]
    pub status: Option<PathBuf>,
    /// Most connections served at once.
    #[arg(long, default_value_t = 32)]
    pub max_connections: usize,
    /// Read the session once, write --html / --json, and exit (no server).
    #[arg(long)]
    pub once: bool,
    /// With --once: write the page here (static: no script).
    #[arg(long, requires = "once")]
    pub html: Option<PathBuf>,
    /// With --once: write the state as JSON here.
    #[arg(long, requires = "once")]
    pub json: Option<PathBuf>,
}

pub fn run(args: WatchArgs) -> Result<()> {
    if !(args.refresh.is_finite() && args.refresh >= 0.2) {
        bail!("--refresh {}: must be at least 0.2 s", args.refresh);
    }
    let mut watch = Watch::open(
        &args.session,
        args.targets.clone(),
        args.status.clone(),
        args.refresh,
    )
    .with_context(|| format!("cannot watch {}", args.session.display()))?;
    if args.once {
        if args.html.is_none() && args.json.is_none() {
            bail!("--once writes the state to --html FILE and/or --json FILE: give at least one");
        }
        watch.look()?;
        let s = watch.snapshot();
        if let Some(path) = &args.html {
            std::fs::write(path, page::page(&s, None))
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        if let Some(path) = &args.json {
            std::fs::write(path, serde_json::to_string_pretty(&s)? + "\n")
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        return Ok(());
    }
    let listener = std::net::TcpListener::bind(args.listen).with_context(|| {
        format!(
            "cannot listen on {} (in use? try --listen 127.0.0.1:PORT)",
            args.listen
        )
    })?;
    let addr = listener.local_addr()?;
    if !addr.ip().is_loopback() {
        eprintln!(
            "warning: serving {} on {addr}, reachable from the network: anyone who reaches this \
             port can read the session (the page is read-only). Use the default 127.0.0.1 and \
             an SSH tunnel to keep it private.",
            args.session.display()
        );
    }
    // A browser that goes away mid-answer must not end the process: the binary restores
    // the default SIGPIPE (quiet `| head`), so it is ignored again here for the server.
    // SAFETY: no handler is installed; SIG_IGN only changes what the signal does.
    let _ = unsafe {
        nix::sys::signal::signal(
            nix::sys::signal::Signal::SIGPIPE,
            nix::sys::signal::SigHandler::SigIgn,
        )
    };
    watch.look()?;
    let shared: Shared = Arc::new(RwLock::new(watch.render()));
    println!(
        "imulab watch: serving {} on http://{addr}/ (Ctrl-C to stop)",
        args.session.display()
    );
    let stopping = Arc::new(AtomicBool::new(false));
    let follower = {
        let (shared, stopping) = (shared.clone(), stopping.clone());
        let period = Duration::from_secs_f64(args.refresh);
        std::thread::Builder::new()
            .name("watch-follow".into())
            .spawn(move || follow_loop(watch, shared, stopping, period))?
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let result = runtime.block_on(serve(
        listener,
        shared,
        args.session.clone(),
        args.max_connections,
        async {
            let _ = tokio::signal::ctrl_c().await;
        },
    ));
    stopping.store(true, Ordering::Relaxed);
    let _ = follower.join();
    result.context("serving the watch page")
}

/// Looks at the session and renders the page every `period` until `stopping`.
fn follow_loop(mut watch: Watch, shared: Shared, stopping: Arc<AtomicBool>, period: Duration) {
    let mut next = Instant::now() + period;
    while !stopping.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(200)));
            continue;
        }
        next += period;
        if next < now {
            next = now + period;
        }
        if let Err(e) = watch.look() {
            // The page says so and keeps the last state.
            watch.follower.problems.truncate(31);
            let line = format!("cannot read the session: {e}");
            if !watch.follower.problems.contains(&line) {
                watch.follower.problems.push(line);
            }
        }
        let rendered: Rendered = watch.render();
        *shared.write().unwrap_or_else(|p| p.into_inner()) = rendered;
    }
}
