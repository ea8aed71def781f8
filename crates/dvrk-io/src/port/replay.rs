//! Recorded frames: [`RecordingLink`] records a session's datagrams, [`ReplayLink`] plays them
//! back under an [`EthPort`], so replayed replies still go through all of the engine's
//! validation. Text format, one datagram per line in hex:
//! ```text
//! # comment
//! > 0100ffc6...   request (control word + FireWire request)
//! < ffd00470...   its reply (FireWire response + 8 bytes extra data)
//! < -             no reply (the request timed out, or was a write)
//! ```
//! A request matches its recording when everything but the transaction label and the header
//! CRC (which depends on the label) is equal; the replayed reply gets the request's label.

use super::eth::EthPort;
use super::{Link, PortError};
use crate::wire::EthRequest;

/// One recorded request and its reply.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub request: Vec<u8>,
    pub reply: Option<Vec<u8>>,
}

/// The Ethernet engine over recorded frames.
pub type ReplayPort = EthPort<ReplayLink>;

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Option<Vec<u8>> {
    let s = s.trim();
    if !s.len().is_multiple_of(2) {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| s.get(i..i + 2).and_then(|h| u8::from_str_radix(h, 16).ok()))
        .collect()
}

/// Error parsing a frames file (setup, not per cycle).
#[derive(Debug, thiserror::Error)]
#[error("frames line {line}: {reason}")]
pub struct FramesParseError {
    pub line: usize,
    pub reason: &'static str,
}

/// Writes frames in the text format.
pub fn frames_to_text(frames: &[Frame]) -> String {
    let mut s = String::new();
    for f in frames {
        s.push_str("> ");
        s.push_str(&hex(&f.request));
        s.push('\n');
        match &f.reply {
            Some(r) => {
                s.push_str("< ");
                s.push_str(&hex(r));
            }
            None => s.push_str("< -"),
        }
        s.push('\n');
    }
    s
}

/// Parses the text format.
pub fn frames_from_text(text: &str) -> Result<Vec<Frame>, FramesParseError> {
    let mut frames = Vec::new();
    let mut pending: Option<Vec<u8>> = None;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        let n = i + 1;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(rest) = line.strip_prefix('>') {
            if pending.is_some() {
                return Err(FramesParseError {
                    line: n,
                    reason: "request without a reply line",
                });
            }
            pending = Some(unhex(rest).ok_or(FramesParseError {
                line: n,
                reason: "bad hex",
            })?);
        } else if let Some(rest) = line.strip_prefix('<') {
            let request = pending.take().ok_or(FramesParseError {
                line: n,
                reason: "reply without a request",
            })?;
            let reply = if rest.trim() == "-" {
                None
            } else {
                Some(unhex(rest).ok_or(FramesParseError {
                    line: n,
                    reason: "bad hex",
                })?)
            };
            frames.push(Frame { request, reply });
        } else {
            return Err(FramesParseError {
                line: n,
                reason: "line must start with '>', '<' or '#'",
            });
        }
    }
    if pending.is_some() {
        return Err(FramesParseError {
            line: text.lines().count(),
            reason: "last request has no reply line",
        });
    }
    Ok(frames)
}

/// Requests equal up to label and header CRC.
fn same_request(a: &[u8], b: &[u8]) -> bool {
    match (EthRequest::parse(a), EthRequest::parse(b)) {
        (Ok(x), Ok(y)) => {
            let mut rx = crate::wire::RequestRepr::parse(&x.packet).ok();
            let mut ry = crate::wire::RequestRepr::parse(&y.packet).ok();
            if let (Some(rx), Some(ry)) = (rx.as_mut(), ry.as_mut()) {
                rx.label = 0;
                ry.label = 0;
            }
            rx.is_some()
                && rx == ry
                && x.control == y.control
                && x.packet.payload() == y.packet.payload()
        }
        _ => a == b,
    }
}

/// Plays recorded frames back.
pub struct ReplayLink {
    frames: Vec<Frame>,
    next: usize,
    looping: bool,
    pending: Option<(usize, u8)>,
}

impl ReplayLink {
    pub fn new(frames: Vec<Frame>) -> Self {
        Self {
            frames,
            next: 0,
            looping: false,
            pending: None,
        }
    }
    pub fn from_text(text: &str) -> Result<Self, FramesParseError> {
        Ok(Self::new(frames_from_text(text)?))
    }
    /// Start over at the end instead of reporting exhaustion.
    pub fn looping(mut self, on: bool) -> Self {
        self.looping = on;
        self
    }
    /// Frames replayed so far.
    pub fn position(&self) -> usize {
        self.next
    }
    pub fn len(&self) -> usize {
        self.frames.len()
    }
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

impl Link for ReplayLink {
    fn send(&mut self, _dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        if self.next >= self.frames.len() {
            if self.looping && !self.frames.is_empty() {
                self.next = 0;
            } else {
                return Err(PortError::ReplayExhausted {
                    frames: self.frames.len() as u32,
                });
            }
        }
        let idx = self.next;
        let Some(f) = self.frames.get(idx) else {
            return Err(PortError::ReplayExhausted {
                frames: self.frames.len() as u32,
            });
        };
        if !same_request(&f.request, datagram) {
            return Err(PortError::ReplayMismatch { index: idx as u32 });
        }
        let label = EthRequest::parse(datagram)
            .map(|r| r.packet.label())
            .unwrap_or(0);
        self.next += 1;
        self.pending = f.reply.as_ref().map(|_| (idx, label));
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        let Some((idx, label)) = self.pending.take() else {
            return Err(PortError::LINK_TIMEOUT);
        };
        let Some(reply) = self.frames.get(idx).and_then(|f| f.reply.as_ref()) else {
            return Err(PortError::LINK_TIMEOUT);
        };
        let n = reply.len().min(buf.len());
        buf[..n].copy_from_slice(&reply[..n]);
        // Response q0 bits 15..10 carry the label: byte 2, bits 7..2 (only on a full response).
        if n > 8
            && let Some(b) = buf.get_mut(2)
        {
            *b = (*b & 0x03) | (label << 2);
            // Responses have a 5-quadlet header whose last quadlet is its CRC (reference §3.1):
            // a recording from a source that sends CRCs keeps them right.
            if n >= 20 && buf[16..20] != [0; 4] {
                let crc = crate::wire::crc32_bzip2(&buf[..16]);
                buf[16..20].copy_from_slice(&crc.to_be_bytes());
            }
        }
        Ok(n)
    }
}

/// Records every request and reply passing through (allocates per frame: a test tool).
pub struct RecordingLink<L: Link> {
    inner: L,
    frames: Vec<Frame>,
}

impl<L: Link> RecordingLink<L> {
    pub fn new(inner: L) -> Self {
        Self {
            inner,
            frames: Vec::new(),
        }
    }
    pub fn frames(&self) -> &[Frame] {
        &self.frames
    }
    pub fn into_frames(self) -> Vec<Frame> {
        self.frames
    }
    pub fn to_text(&self) -> String {
        frames_to_text(&self.frames)
    }
    pub fn inner_mut(&mut self) -> &mut L {
        &mut self.inner
    }
}

impl<L: Link> Link for RecordingLink<L> {
    fn send(&mut self, dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        self.frames.push(Frame {
            request: datagram.to_vec(),
            reply: None,
        });
        self.inner.send(dest_node, datagram)
    }
    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        let n = self.inner.recv(buf)?;
        if let Some(f) = self.frames.last_mut()
            && f.reply.is_none()
        {
            f.reply = buf.get(..n).map(<[u8]>::to_vec);
        }
        Ok(n)
    }
    fn discard_pending(&mut self, buf: &mut [u8]) -> usize {
        self.inner.discard_pending(buf)
    }
}
