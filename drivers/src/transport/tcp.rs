//! TCP client for serial-over-network servers (ser2net, socat, receiver NTRIP-style ports):
//! the remote end's bytes are the device's bytes.

use std::time::Duration;

use tokio::net::TcpStream;

use super::{StreamTransport, TransportError};

/// A connected TCP stream.
pub type TcpTransport = StreamTransport<TcpStream>;

/// Connects to `address` (`host:port`) within `connect_timeout`.
pub async fn connect_tcp(
    address: &str,
    connect_timeout: Duration,
    idle_timeout: Option<Duration>,
) -> Result<TcpTransport, TransportError> {
    let device = format!("tcp://{address}");
    let stream = match tokio::time::timeout(connect_timeout, TcpStream::connect(address)).await {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => return Err(TransportError::Open { device, source: e }),
        Err(_) => {
            return Err(TransportError::Open {
                device,
                source: std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!("connect timed out after {connect_timeout:?}"),
                ),
            })
        }
    };
    // Small device messages: do not let Nagle delay commands we send.
    let _ = stream.set_nodelay(true);
    Ok(StreamTransport::new(stream, device, idle_timeout))
}
