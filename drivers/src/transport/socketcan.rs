//! SocketCAN (Linux `can0`, `vcan0`, ...) through the `socketcan` crate's raw socket,
//! classic and FD frames, converted to and from [`CanFrame`]. An interface that goes down or
//! is removed surfaces as [`TransportError::Vanished`].
//!
//! Why not `socketcan::tokio::CanFdSocket::read_frame`: it waits for readability only, and a
//! link going down makes the kernel raise a socket error without making the socket readable,
//! so a reader waiting there never wakes (pinned by `tests/socketcan_guest.rs` in the QEMU
//! guest). Here the socket is registered with tokio's `AsyncFd` and waited on for
//! `READABLE | ERROR`, so the read returns `ENETDOWN` at once.

use std::time::Duration;

use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

use socketcan::{
    CanAnyFrame, CanDataFrame, CanErrorFrame, CanFdFrame, CanRemoteFrame, EmbeddedFrame,
    ExtendedId, Frame, Id, Socket, SocketOptions, StandardId,
};

use socketcan::id::FdFlags;

use super::TransportError;
use crate::codec::can::{CanFrame, CanKind};

/// An open CAN (FD-capable) raw socket bound to one interface.
pub struct SocketCanTransport {
    socket: AsyncFd<socketcan::CanFdSocket>,
    interface: String,
    idle_timeout: Option<Duration>,
}

impl std::fmt::Debug for SocketCanTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SocketCanTransport")
            .field("interface", &self.interface)
            .finish()
    }
}

/// Converts a received socketcan frame.
pub fn from_socketcan(frame: &CanAnyFrame) -> Result<CanFrame, String> {
    match frame {
        CanAnyFrame::Normal(f) => CanFrame::data(f.raw_id(), f.is_extended(), f.data()),
        CanAnyFrame::Remote(f) => CanFrame::remote(f.raw_id(), f.is_extended(), f.dlc() as u8),
        CanAnyFrame::Error(f) => CanFrame::error(f.error_bits(), f.data()),
        CanAnyFrame::Fd(f) => CanFrame::fd(
            f.raw_id(),
            f.is_extended(),
            f.is_brs(),
            f.is_esi(),
            f.data(),
        ),
    }
}

fn socketcan_id(frame: &CanFrame) -> Result<Id, String> {
    let id = if frame.is_extended() {
        ExtendedId::new(frame.id()).map(Id::Extended)
    } else {
        u16::try_from(frame.id())
            .ok()
            .and_then(StandardId::new)
            .map(Id::Standard)
    };
    id.ok_or_else(|| format!("CAN id {:#x} out of range", frame.id()))
}

/// Converts a frame for sending.
pub fn to_socketcan(frame: &CanFrame) -> Result<CanAnyFrame, String> {
    let unbuildable = || format!("socketcan refused frame {frame:?}");
    Ok(match frame.kind() {
        CanKind::Data => CanAnyFrame::Normal(
            CanDataFrame::new(socketcan_id(frame)?, frame.payload()).ok_or_else(unbuildable)?,
        ),
        CanKind::Remote => CanAnyFrame::Remote(
            CanRemoteFrame::new_remote(socketcan_id(frame)?, frame.len())
                .ok_or_else(unbuildable)?,
        ),
        CanKind::Error => CanAnyFrame::Error(
            CanErrorFrame::new_error(frame.id(), frame.payload()).map_err(|e| e.to_string())?,
        ),
        CanKind::Fd { brs, esi } => {
            let mut flags = FdFlags::empty();
            flags.set(FdFlags::BRS, brs);
            flags.set(FdFlags::ESI, esi);
            CanAnyFrame::Fd(
                CanFdFrame::with_flags(socketcan_id(frame)?, frame.payload(), flags)
                    .ok_or_else(unbuildable)?,
            )
        }
    })
}

impl SocketCanTransport {
    /// Opens a raw CAN FD socket on `interface`. Must run inside a tokio runtime.
    pub fn open(interface: &str, idle_timeout: Option<Duration>) -> Result<Self, TransportError> {
        let open_error = |source| TransportError::Open {
            device: interface.to_string(),
            source,
        };
        let socket = socketcan::CanFdSocket::open(interface).map_err(open_error)?;
        socket.set_nonblocking(true).map_err(open_error)?;
        // SAFETY: the CanFdSocket owns its descriptor and keeps it open, unchanged, until it
        // is dropped; the AsyncFd owns the CanFdSocket and deregisters before dropping it.
        let socket =
            unsafe { AsyncFd::register(socket) }.map_err(|e| open_error(e.into_parts().1))?;
        Ok(SocketCanTransport {
            socket,
            interface: interface.to_string(),
            idle_timeout,
        })
    }

    /// Asks the kernel for a receive queue of `bytes`, so a burst or a reader that is late
    /// (a loaded bench PC) overflows nothing: `SO_RCVBUFFORCE` where the process has
    /// CAP_NET_ADMIN, else `SO_RCVBUF` (which the kernel caps at `net.core.rmem_max`). Each
    /// queued frame costs the kernel about 1 KiB of socket memory, not 16 bytes.
    pub fn set_receive_buffer(&self, bytes: usize) -> Result<(), TransportError> {
        let bytes = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
        let socket = self.socket.get_ref();
        socket
            .set_socket_option_int(libc::SOL_SOCKET, libc::SO_RCVBUFFORCE, bytes)
            .or_else(|_| socket.set_socket_option_int(libc::SOL_SOCKET, libc::SO_RCVBUF, bytes))
            .map_err(|e| TransportError::from_io(&self.interface, e))
    }

    /// Receives the next frame.
    pub async fn recv(&mut self) -> Result<CanFrame, TransportError> {
        let read = self
            .socket
            .async_io(Interest::READABLE | Interest::ERROR, |s| s.read_frame());
        let result = match self.idle_timeout {
            Some(t) => {
                tokio::time::timeout(t, read)
                    .await
                    .map_err(|_| TransportError::Timeout {
                        device: self.interface.clone(),
                        after: t,
                    })?
            }
            None => read.await,
        };
        let frame = result.map_err(|e| TransportError::from_io(&self.interface, e))?;
        from_socketcan(&frame).map_err(|reason| TransportError::Protocol {
            device: self.interface.clone(),
            reason,
        })
    }

    /// Sends one frame.
    pub async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        let frame = to_socketcan(frame).map_err(TransportError::Config)?;
        self.socket
            .async_io(Interest::WRITABLE | Interest::ERROR, |s| {
                s.write_frame(&frame)
            })
            .await
            .map(|_| ())
            .map_err(|e| TransportError::from_io(&self.interface, e))
    }
}
