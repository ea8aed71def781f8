//! The MCAP shell: writes the bridge's topics to an MCAP file with `ros2msg` schemas and CDR
//! payloads, the layout `ros2 bag` (rosbag2_storage_mcap), Foxglove and PlotJuggler read.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use dvrk_ipc::{CompensationStatusV4, JawStateV1, JointStateV2, PoseV2};
use mcap::records::MessageHeader;

use crate::convert::{Encoder, OutTopic};
use crate::error::BridgeError;
use crate::source::Sink;

/// The longest a chunk stays open: what a SIGKILL or a power loss can cost of a recording.
pub const CHUNK_INTERVAL: Duration = Duration::from_secs(1);

/// An MCAP file being written: one channel per recorded [`OutTopic`], named by its ROS 2 topic
/// name (`/PSM1/compensated/local/measured_cp`, `/PSM1/measured_js`).
///
/// The file is written at its own name from the start and survives any end of the recording:
/// - a chunk is closed, flushed and synced to the disk at least every [`CHUNK_INTERVAL`] (and
///   whenever it reaches the writer's chunk size), so after SIGKILL, a power loss or a full disk
///   a streaming reader (the `mcap` libraries' non-seeking readers, `mcap recover`) reads every
///   message up to the last finished chunk;
/// - [`McapSink::finish`] writes the summary and footer (a clean stop: SIGINT, SIGTERM,
///   `--seconds`, or an error of the source), so the seeking readers open the file too;
/// - nothing is ever deleted: after a write error (a full disk) the file keeps every finished
///   chunk.
///
/// An existing path is refused ([`McapSink::create`]): a recording never replaces a file.
///
/// Log and publish times are the message's ROS stamp (the sample time in CLOCK_REALTIME ns), and
/// the MCAP sequence is the low 32 bits of the sidecar's `seq`.
pub struct McapSink {
    encoder: Encoder,
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    /// The same open file as the writer's, to sync each closed chunk to the disk.
    file: File,
    /// When the open chunk was started (the last chunk closed).
    chunk_since: Instant,
    /// Channel of each topic of [`OutTopic::RECORDED`] that is recorded.
    channels: [Option<u16>; OutTopic::RECORDED.len()],
    payload: Vec<u8>,
    written: u64,
}

impl core::fmt::Debug for McapSink {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("McapSink")
            .field("path", &self.path)
            .field("written", &self.written)
            .finish_non_exhaustive()
    }
}

impl McapSink {
    /// Starts the file that will become `path` and registers the schemas and the channels of
    /// the compensated topics and, with `raw`, of the uncompensated ones.
    pub fn create(encoder: Encoder, path: &Path, raw: bool) -> Result<Self, BridgeError> {
        if path.file_name().is_none() {
            return Err(BridgeError::InvalidArgument {
                what: "--out",
                value: path.display().to_string(),
                reason: "not a file path",
            });
        }
        // Created exclusively: an existing file (an earlier recording), a device node, a FIFO or
        // a symbolic link (even a dangling one) is never opened, truncated or replaced.
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|source| BridgeError::CreateFile {
                path: path.to_owned(),
                source: if source.kind() == std::io::ErrorKind::AlreadyExists {
                    std::io::Error::new(
                        source.kind(),
                        "it exists; record never replaces a file: remove it or give a new --out",
                    )
                } else {
                    source
                },
            })?;
        let io_err = |source| BridgeError::CreateFile {
            path: path.to_owned(),
            source,
        };
        let sync = file.try_clone().map_err(io_err)?;
        // The new directory entry reaches the disk too, so a power loss keeps the file.
        if let Some(dir) = path.parent() {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            };
            File::open(dir).and_then(|d| d.sync_all()).map_err(io_err)?;
        }
        let mcap_err = |source| BridgeError::Mcap {
            path: path.to_owned(),
            source,
        };
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .create(BufWriter::new(file))
            .map_err(&mcap_err)?;
        let mut channels = [None; OutTopic::RECORDED.len()];
        let mut schemas: BTreeMap<&str, u16> = BTreeMap::new();
        for (i, t) in OutTopic::RECORDED.into_iter().enumerate() {
            if t.is_raw() && !raw {
                continue;
            }
            let ty = t.msg_type();
            let schema = match schemas.get(ty.ros_name) {
                Some(&id) => id,
                None => {
                    let id = writer
                        .add_schema(ty.ros_name, "ros2msg", ty.schema.as_bytes())
                        .map_err(mcap_err)?;
                    schemas.insert(ty.ros_name, id);
                    id
                }
            };
            channels[i] = Some(
                writer
                    .add_channel(
                        schema,
                        &t.ros_name(&encoder.frames.arm),
                        "cdr",
                        &BTreeMap::new(),
                    )
                    .map_err(mcap_err)?,
            );
        }
        let mut sink = McapSink {
            encoder,
            path: path.to_owned(),
            writer,
            file: sync,
            chunk_since: Instant::now(),
            channels,
            payload: Vec::new(),
            written: 0,
        };
        // The header, schemas and channels on the disk before the first message.
        sink.close_chunk()?;
        Ok(sink)
    }

    /// Closes the open chunk, writes it out and syncs it to the disk: from here on a streaming
    /// reader reads every message written so far, whatever happens to this process.
    fn close_chunk(&mut self) -> Result<(), BridgeError> {
        self.writer.flush().map_err(|source| BridgeError::Mcap {
            path: self.path.clone(),
            source,
        })?;
        self.file
            .sync_data()
            .map_err(|source| BridgeError::CreateFile {
                path: self.path.clone(),
                source,
            })?;
        self.chunk_since = Instant::now();
        Ok(())
    }

    /// Messages written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes the last chunk, the summary and the footer, and syncs the file; returns the
    /// number of messages. On error (a full disk) the file is kept as it is: every chunk closed
    /// before is readable.
    pub fn finish(mut self) -> Result<u64, BridgeError> {
        let path = self.path.clone();
        self.writer.finish().map_err(|source| BridgeError::Mcap {
            path: path.clone(),
            source,
        })?;
        let file = self
            .writer
            .into_inner()
            .into_inner()
            .map_err(|e| BridgeError::CreateFile {
                path: path.clone(),
                source: e.into_error(),
            })?;
        file.sync_all()
            .map_err(|source| BridgeError::CreateFile { path, source })?;
        Ok(self.written)
    }

    fn write(&mut self, t: OutTopic, header: &dvrk_ipc::Header) -> Result<(), BridgeError> {
        let Some(channel_id) = OutTopic::RECORDED
            .iter()
            .position(|&x| x == t)
            .and_then(|i| self.channels[i])
        else {
            // A topic without a channel (raw while recording compensated only): not recorded.
            return Ok(());
        };
        let stamp = crate::convert::ros_time(header).as_unix_ns();
        let time = u64::try_from(stamp).unwrap_or(0);
        self.payload.clear();
        self.payload
            .extend_from_slice(&crate::cdr::ENCAPSULATION_CDR_LE);
        self.payload.extend_from_slice(self.encoder.last_body());
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id,
                    sequence: header.seq as u32,
                    log_time: time,
                    publish_time: time,
                },
                &self.payload,
            )
            .map_err(|source| BridgeError::Mcap {
                path: self.path.clone(),
                source,
            })?;
        self.written += 1;
        if self.chunk_since.elapsed() >= CHUNK_INTERVAL {
            self.close_chunk()?;
        }
        Ok(())
    }
}

impl Sink for McapSink {
    fn pose(&mut self, topic: OutTopic, p: &PoseV2) -> Result<(), BridgeError> {
        self.encoder.pose(topic, p);
        self.write(topic, &p.header)
    }

    fn joints(&mut self, topic: OutTopic, js: &JointStateV2) -> Result<(), BridgeError> {
        self.encoder.joints(js);
        self.write(topic, &js.header)
    }

    fn jaw(&mut self, topic: OutTopic, jaw: &JawStateV1) -> Result<(), BridgeError> {
        self.encoder.jaw(jaw);
        self.write(topic, &jaw.header)
    }

    fn status(&mut self, s: &CompensationStatusV4) -> Result<(), BridgeError> {
        self.encoder.status(s);
        self.write(OutTopic::Status, &s.header)
    }
}
