//! The HTTP side of `imulab watch`: axum routes served by hyper from our own accept loop.
//!
//! - Read-only: GET and HEAD only (anything else is 405); no route changes anything.
//! - Bound to loopback, a request whose `Host` header does not name this machine
//!   (localhost, 127.0.0.0/8, [::1]) is refused with 403: a page of another site whose name
//!   was made to resolve to 127.0.0.1 (DNS rebinding) cannot read the session.
//! - Files: `/files/NAME` serves only a regular file (not a link) directly inside the
//!   session directory, by a name without any path separator, and at most
//!   [`MAX_FILE_BYTES`]; nothing outside the session can be named.
//! - At most `max_connections` connections at once (the one past that gets 503 and is
//!   closed), each with a 10 s limit to send its request head and a 10 min life.
//!
//! Hand-written accept loop: `axum::serve` has no bound on connections.

use axum::body::Body;
use axum::extract::{Path as UrlPath, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;

/// Largest session file served (session.toml, small chunk files); larger ones are copied
/// from the machine, not through the page.
pub const MAX_FILE_BYTES: u64 = 64 << 20;

const HEAD_TIMEOUT: Duration = Duration::from_secs(10);
const CONNECTION_LIFE: Duration = Duration::from_secs(600);

/// What the pages are made of, replaced by the follower at every refresh.
#[derive(Debug, Clone, Default)]
pub struct Rendered {
    pub page: String,
    pub fragment: String,
    pub json: String,
}

/// Shared between the follower (writes) and the server (reads).
pub type Shared = Arc<RwLock<Rendered>>;

#[derive(Clone)]
struct AppState {
    rendered: Shared,
    session_dir: PathBuf,
    loopback_only: bool,
}

/// Whether a `Host` header value names this machine.
pub fn is_local_host(host: &str) -> bool {
    let host = host.trim();
    let name = if let Some(rest) = host.strip_prefix('[') {
        match rest.split_once(']') {
            Some((inside, port)) if port.is_empty() || port.starts_with(':') => inside,
            _ => return false,
        }
    } else {
        match host.rsplit_once(':') {
            Some((name, port)) if port.bytes().all(|b| b.is_ascii_digit()) => name,
            Some(_) => return false,
            None => host,
        }
    };
    if name.eq_ignore_ascii_case("localhost") {
        return true;
    }
    name.parse::<std::net::IpAddr>()
        .is_ok_and(|ip| ip.is_loopback())
}

/// Method and Host checks in front of every route.
async fn guard(State(app): State<AppState>, req: Request, next: Next) -> Response {
    if *req.method() != Method::GET && *req.method() != Method::HEAD {
        let mut r = (
            StatusCode::METHOD_NOT_ALLOWED,
            "imulab watch is read-only: only GET and HEAD are answered\n",
        )
            .into_response();
        r.headers_mut()
            .insert(header::ALLOW, HeaderValue::from_static("GET, HEAD"));
        return r;
    }
    if app.loopback_only {
        let host = req
            .headers()
            .get(header::HOST)
            .and_then(|h| h.to_str().ok())
            .unwrap_or("");
        if !is_local_host(host) {
            let msg = format!(
                "Host `{}` is not this machine: imulab watch listens on loopback and answers \
                 only requests for localhost, 127.0.0.1 or [::1] (use --listen to serve other names)\n",
                host.escape_debug()
            );
            return (StatusCode::FORBIDDEN, msg).into_response();
        }
    }
    let mut r = next.run(req).await;
    let h = r.headers_mut();
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; \
             img-src data:; connect-src 'self'; base-uri 'none'; form-action 'none'",
        ),
    );
    r
}

fn html(text: String) -> Response {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], text).into_response()
}

async fn page(State(app): State<AppState>) -> Response {
    html(read(&app.rendered).page.clone())
}

async fn fragment(State(app): State<AppState>) -> Response {
    html(read(&app.rendered).fragment.clone())
}

async fn state_json(State(app): State<AppState>) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        read(&app.rendered).json.clone(),
    )
        .into_response()
}

fn read(shared: &Shared) -> std::sync::RwLockReadGuard<'_, Rendered> {
    shared.read().unwrap_or_else(|p| p.into_inner())
}

fn not_found() -> Response {
    (StatusCode::NOT_FOUND, "not found\n").into_response()
}

/// A file directly inside the session directory (see the module docs).
async fn file(State(app): State<AppState>, UrlPath(name): UrlPath<String>) -> Response {
    let bad = name.is_empty()
        || name.starts_with('.')
        || name.contains(['/', '\\', '\0'])
        || name.chars().any(char::is_control);
    if bad {
        return not_found();
    }
    let path = app.session_dir.join(&name);
    let Ok(meta) = std::fs::symlink_metadata(&path) else {
        return not_found();
    };
    if !meta.file_type().is_file() {
        return not_found();
    }
    if meta.len() > MAX_FILE_BYTES {
        let msg = format!(
            "{name} is {} bytes, more than the {} MiB the page serves: copy it from the machine\n",
            meta.len(),
            MAX_FILE_BYTES >> 20
        );
        return (StatusCode::PAYLOAD_TOO_LARGE, msg).into_response();
    }
    let Ok(bytes) = tokio::fs::read(&path).await else {
        return not_found();
    };
    let kind = match path.extension().and_then(|e| e.to_str()) {
        Some("toml" | "json" | "txt" | "csv" | "log") => "text/plain; charset=utf-8",
        Some("h5") => "application/x-hdf5",
        _ => "application/octet-stream",
    };
    let mut headers = HeaderMap::new();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
    (headers, Body::from(bytes)).into_response()
}

/// The routes, with the guard in front.
fn router(rendered: Shared, session_dir: PathBuf, loopback_only: bool) -> Router {
    let state = AppState {
        rendered,
        session_dir,
        loopback_only,
    };
    Router::new()
        .route("/", get(page))
        .route("/fragment", get(fragment))
        .route("/state.json", get(state_json))
        .route("/files/{name}", get(file))
        .fallback(|| async { not_found() })
        .layer(middleware::from_fn_with_state(state.clone(), guard))
        .with_state(state)
}

/// Serves until `stop` resolves. `listener` is already bound (so the caller can print its
/// address); it is loopback-only when its address is a loopback one.
pub async fn serve(
    listener: std::net::TcpListener,
    rendered: Shared,
    session_dir: PathBuf,
    max_connections: usize,
    stop: impl std::future::Future<Output = ()>,
) -> std::io::Result<()> {
    listener.set_nonblocking(true)?;
    let loopback_only = listener.local_addr()?.ip().is_loopback();
    let listener = TcpListener::from_std(listener)?;
    let app = router(rendered, session_dir, loopback_only);
    let slots = Arc::new(Semaphore::new(max_connections.max(1)));
    tokio::pin!(stop);
    loop {
        let (stream, _peer): (tokio::net::TcpStream, SocketAddr) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                // Out of descriptors and the like: wait, do not spin.
                Err(_) => {
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = &mut stop => return Ok(()),
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            tokio::spawn(async move {
                let mut stream = stream;
                let busy = b"HTTP/1.1 503 Service Unavailable\r\nConnection: close\r\nContent-Length: 33\r\n\r\ntoo many connections, try again\r\n";
                let _ = tokio::time::timeout(HEAD_TIMEOUT, stream.write_all(busy)).await;
            });
            continue;
        };
        let service = TowerToHyperService::new(app.clone());
        tokio::spawn(async move {
            let connection = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(HEAD_TIMEOUT)
                .serve_connection(TokioIo::new(stream), service);
            let _ = tokio::time::timeout(CONNECTION_LIFE, connection).await;
            drop(slot);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::is_local_host;

    #[test]
    fn local_hosts() {
        for ok in [
            "localhost",
            "localhost:8642",
            "127.0.0.1:80",
            "127.1.2.3",
            "[::1]:8642",
            "[::1]",
            "LOCALHOST:1",
        ] {
            assert!(is_local_host(ok), "{ok}");
        }
        for bad in [
            "",
            "evil.example",
            "evil.example:8642",
            "127.0.0.1.evil.example",
            "[::1]x",
            "10.0.0.1:80",
            "localhost.evil:80",
            "[::2]:1",
            "127.0.0.1:80:80",
        ] {
            assert!(!is_local_host(bad), "{bad}");
        }
    }
}
