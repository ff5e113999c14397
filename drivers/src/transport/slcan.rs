//! slcan adapters (Lawicel protocol over a serial port, e.g. CANable with slcan firmware,
//! USBtin, CAN232): opens the channel at a bitrate and then yields CAN frames. The byte
//! handling is [`crate::codec::slcan`]; this only adds the serial port and the handshake.

use std::time::Duration;

use super::serial::{open_serial, SerialConfig, SerialTransport};
use super::{ByteSource, TransportError};
use crate::codec::can::CanFrame;
use crate::codec::slcan::{bitrate_code, SlcanDecoder, SlcanEncoder, SlcanMessage, BITRATES};
use crate::codec::{Decoder, Encoder};
use crate::types::DecoderStats;

/// How long to wait for the adapter's reply to one command.
pub const COMMAND_TIMEOUT: Duration = Duration::from_secs(1);

/// An open slcan channel.
#[derive(Debug)]
pub struct SlcanTransport {
    port: SerialTransport,
    decoder: SlcanDecoder,
    buf: Box<[u8; 4096]>,
}

impl SlcanTransport {
    /// Opens the serial port, closes any open channel, sets `bitrate` (one of
    /// [`BITRATES`]) and opens the channel (listen-only when asked). Each command must be
    /// answered by `\r` within [`COMMAND_TIMEOUT`]; a BEL reply is a protocol error.
    pub async fn open(
        serial: &SerialConfig,
        bitrate: u32,
        listen_only: bool,
    ) -> Result<Self, TransportError> {
        let code = bitrate_code(bitrate).ok_or_else(|| {
            TransportError::Config(format!(
                "slcan bitrate {bitrate} bit/s is not one of {BITRATES:?}"
            ))
        })?;
        let port = open_serial(serial)?;
        let mut transport = SlcanTransport {
            port,
            decoder: SlcanDecoder::new(),
            buf: Box::new([0u8; 4096]),
        };
        // Close first: an adapter left open refuses `Sn`. Its reply (OK or BEL) is moot.
        transport.command(&SlcanMessage::Close).await.ok();
        transport.command(&SlcanMessage::Bitrate(code)).await?;
        let open = if listen_only {
            SlcanMessage::ListenOnly
        } else {
            SlcanMessage::Open
        };
        transport.command(&open).await?;
        Ok(transport)
    }

    async fn send_message(&mut self, message: &SlcanMessage) -> Result<(), TransportError> {
        let mut bytes = Vec::with_capacity(32);
        SlcanEncoder
            .encode(message, &mut bytes)
            .map_err(|e| TransportError::Config(e.to_string()))?;
        self.port.write_all(&bytes).await
    }

    /// Sends a command and waits for OK; frames arriving meanwhile are dropped.
    async fn command(&mut self, message: &SlcanMessage) -> Result<(), TransportError> {
        self.send_message(message).await?;
        let device = self.port.device().to_string();
        let wait = async {
            loop {
                match self.next_message().await? {
                    SlcanMessage::Ok => return Ok(()),
                    SlcanMessage::Error => {
                        return Err(TransportError::Protocol {
                            device: device.clone(),
                            reason: format!("adapter refused {message:?} (BEL)"),
                        })
                    }
                    _ => continue,
                }
            }
        };
        tokio::time::timeout(COMMAND_TIMEOUT, wait)
            .await
            .map_err(|_| TransportError::Timeout {
                device: device.clone(),
                after: COMMAND_TIMEOUT,
            })?
    }

    async fn next_message(&mut self) -> Result<SlcanMessage, TransportError> {
        loop {
            if let Some(m) = self.decoder.poll() {
                return Ok(m);
            }
            let n = self.port.read(&mut self.buf[..]).await?;
            self.decoder.push(&self.buf[..n]);
        }
    }

    /// Receives the next CAN frame with the adapter timestamp (ms), if enabled.
    /// Other adapter output (acks, BEL after a failed transmit) is skipped.
    pub async fn recv(&mut self) -> Result<(CanFrame, Option<u16>), TransportError> {
        loop {
            match self.next_message().await? {
                SlcanMessage::Frame {
                    frame,
                    timestamp_ms,
                } => return Ok((frame, timestamp_ms)),
                SlcanMessage::Error => {
                    tracing::debug!("slcan {}: adapter reported an error", self.port.device())
                }
                _ => {}
            }
        }
    }

    /// Transmits one classic frame (fire and forget; the adapter's `z`/`Z` ack is skipped
    /// by [`SlcanTransport::recv`]).
    pub async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.send_message(&SlcanMessage::Frame {
            frame: *frame,
            timestamp_ms: None,
        })
        .await
    }

    /// Closes the channel (`C`), best effort.
    pub async fn close(mut self) -> Result<(), TransportError> {
        self.send_message(&SlcanMessage::Close).await
    }

    /// The slcan decoder's counters.
    pub fn stats(&self) -> DecoderStats {
        self.decoder.stats()
    }
}
