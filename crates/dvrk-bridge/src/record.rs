//! The MCAP shell: writes the bridge's topics to an MCAP file with `ros2msg` schemas and CDR
//! payloads, the layout `ros2 bag` (rosbag2_storage_mcap), Foxglove and PlotJuggler read.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::BufWriter;
use std::os::unix::fs::{FileExt, MetadataExt};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::MessageHeader;

use crate::convert::{Encoder, OutTopic};
use crate::error::BridgeError;
use crate::source::Sample;

/// The longest a chunk stays open: what a SIGKILL or a power loss can cost of a recording.
pub const CHUNK_INTERVAL: Duration = Duration::from_secs(1);

/// The payload size at which the sink closes a chunk before [`CHUNK_INTERVAL`] (about a quarter
/// of a second of one arm at 1.5 kHz): a full disk then costs at most this much of what was
/// recorded, and each chunk is closed by the sink, which puts the interim footer after it.
const CLOSE_AT_BYTES: u64 = 1 << 20;
/// The size at which the writer would close a chunk on its own, without the interim footer:
/// never reached, the sink closes at [`CLOSE_AT_BYTES`] (plus one message). The open chunk is
/// held in memory (allocated once, at this size).
const CHUNK_BYTES: u64 = 4 << 20;

/// What follows the last closed chunk until the next one: a Footer record that says there is no
/// summary (opcode 0x02, length 20, `summary_start` 0, `summary_offset_start` 0, `summary_crc`
/// 0) and the closing magic. With it the file is a complete MCAP without an index at every
/// moment but while a chunk is being written, so the readers that start from the footer (the
/// Python `mcap` package's `make_reader` on a file) open it after SIGKILL or a power loss too,
/// and read it in order.
const INTERIM_FOOTER: [u8; 37] = {
    let mut f = [0u8; 37];
    f[0] = 0x02;
    f[1] = 20;
    let magic = *b"\x89MCAP0\r\n";
    let mut i = 0;
    while i < 8 {
        f[29 + i] = magic[i];
        i += 1;
    }
    f
};

/// An MCAP file being written: one channel per arm and recorded [`OutTopic`], named by its ROS 2
/// topic name (`/PSM1/compensated/local/measured_cp`, `/PSM2/measured_js`).
///
/// The file is written at its own name from the start and survives any end of the recording:
/// - a chunk is closed, flushed and synced to the disk at least every [`CHUNK_INTERVAL`] (and at
///   `CLOSE_AT_BYTES`), and an interim footer without summary (`INTERIM_FOOTER`) follows it
///   until the next one, so after SIGKILL, a power loss or a full disk the readers that start
///   from the footer and the streaming ones read every message up to the last finished chunk
///   (only while a chunk is being written, a few ms a second, do the streaming ones alone);
/// - [`McapSink::finish`] writes the summary and footer (a clean stop: SIGINT, SIGTERM,
///   `--seconds`, or an error of the source), so readers find the file's index;
/// - nothing recorded is ever deleted: after a write error (a full disk) the file keeps every
///   finished chunk. Only a file that holds no message is removed, by [`McapSink::discard`].
///
/// An existing path is refused ([`McapSink::create`]): a recording never replaces a file.
///
/// Log and publish times are the message's ROS stamp (the sample time in CLOCK_REALTIME ns), and
/// the MCAP sequence is the low 32 bits of the sidecar's `seq`.
pub struct McapSink {
    arms: Vec<McapArm>,
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    /// The same open file as the writer's, to sync each closed chunk to the disk.
    file: File,
    /// When the open chunk was started (the last chunk closed).
    chunk_since: Instant,
    payload: Vec<u8>,
    written: u64,
    /// The end of the last closed chunk, where the interim footer starts (0 before the first).
    good_end: u64,
    /// Payload bytes in the open chunk.
    chunk_bytes: u64,
    /// A write failed: the file ends at its last closed chunk and its interim footer, and
    /// [`McapSink::finish`] leaves it so (a summary written later would index the lost chunk).
    failed: bool,
}

/// One arm's encoder, channels and count.
struct McapArm {
    encoder: Encoder,
    /// Channel of each topic of [`OutTopic::RECORDED`] that is recorded.
    channels: [Option<u16>; OutTopic::RECORDED.len()],
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
    /// Creates the file `path` and registers the schemas and, for the arm of each of
    /// `encoders`, the channels of the compensated topics and, with `raw`, of the uncompensated
    /// ones.
    pub fn create(encoders: Vec<Encoder>, path: &Path, raw: bool) -> Result<Self, BridgeError> {
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
        // Chunks held in memory and written out whole when closed (`disable_seeking`), so the
        // file does not change between two closes and the interim footer stays valid.
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .chunk_size(Some(CHUNK_BYTES))
            .disable_seeking(true)
            .create(BufWriter::new(file))
            .map_err(&mcap_err)?;
        let mut schemas: BTreeMap<&str, u16> = BTreeMap::new();
        let mut arms = Vec::with_capacity(encoders.len());
        for encoder in encoders {
            let mut channels = [None; OutTopic::RECORDED.len()];
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
            arms.push(McapArm {
                encoder,
                channels,
                written: 0,
            });
        }
        let mut sink = McapSink {
            arms,
            path: path.to_owned(),
            writer,
            file: sync,
            chunk_since: Instant::now(),
            payload: Vec::new(),
            written: 0,
            good_end: 0,
            chunk_bytes: 0,
            failed: false,
        };
        // The header, schemas and channels on the disk before the first message.
        sink.close_chunk()?;
        Ok(sink)
    }

    /// Closes the open chunk, writes it out, puts the interim footer after it and syncs it to
    /// the disk: from here on every reader reads every message written so far, whatever
    /// happens to this process. On a write error (a full disk) the file is cut back to the end
    /// of the last chunk closed before, with its footer.
    fn close_chunk(&mut self) -> Result<(), BridgeError> {
        let path = self.path.clone();
        if let Err(source) = self.writer.flush() {
            self.restore_footer();
            return Err(BridgeError::Mcap { path, source });
        }
        let io_err = |source| BridgeError::CreateFile {
            path: path.clone(),
            source,
        };
        // The writer's offset (this handle shares its file description): the end of the chunk.
        // The footer is written there without moving it, so the next chunk overwrites it.
        let end = std::io::Seek::stream_position(&mut self.file).map_err(io_err)?;
        self.good_end = end;
        let written = self.file.write_all_at(&INTERIM_FOOTER, end);
        if let Err(e) = written.and_then(|()| self.file.sync_data()) {
            self.restore_footer();
            return Err(io_err(e));
        }
        self.chunk_since = Instant::now();
        self.chunk_bytes = 0;
        Ok(())
    }

    /// After a failed write: cuts the file back to the end of the last closed chunk and puts
    /// the interim footer there again (the cut frees the space it needs). Best effort: the
    /// chunks before stay readable by a streaming reader in any case.
    fn restore_footer(&mut self) {
        self.failed = true;
        if self.good_end == 0 {
            return;
        }
        if self.file.set_len(self.good_end).is_ok()
            && self
                .file
                .write_all_at(&INTERIM_FOOTER, self.good_end)
                .is_ok()
        {
            let _ = self.file.sync_data();
        }
    }

    /// Messages written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Messages written so far of the arm of `encoders[arm]` given to [`McapSink::create`].
    pub fn written_of(&self, arm: usize) -> u64 {
        self.arms.get(arm).map_or(0, |a| a.written)
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
        if self.failed {
            return Err(BridgeError::CreateFile {
                path,
                source: std::io::Error::other(
                    "a write failed earlier: the file ends at its last closed chunk",
                ),
            });
        }
        if let Err(source) = self.writer.finish() {
            self.restore_footer();
            return Err(BridgeError::Mcap {
                path: path.clone(),
                source,
            });
        }
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

    /// Removes the file if no message was written to it and it is still the file this sink
    /// created (same device and inode at its name): a recording that got nothing leaves nothing
    /// behind, and a file put at the name since is never touched. Returns whether it was removed.
    pub fn discard(mut self) -> Result<bool, BridgeError> {
        if self.written > 0 {
            return Ok(false);
        }
        // The summary and footer are not needed: the file goes. A write error here changes
        // nothing about that.
        let _ = self.writer.finish();
        let ours = self
            .file
            .metadata()
            .map_err(|source| BridgeError::CreateFile {
                path: self.path.clone(),
                source,
            })?;
        match std::fs::symlink_metadata(&self.path) {
            Ok(now) if now.dev() == ours.dev() && now.ino() == ours.ino() => {}
            _ => return Ok(false),
        }
        std::fs::remove_file(&self.path).map_err(|source| BridgeError::CreateFile {
            path: self.path.clone(),
            source,
        })?;
        Ok(true)
    }

    /// Writes `s`, a sample of the arm of `encoders[arm]` given to [`McapSink::create`].
    pub fn write(&mut self, arm: usize, s: &Sample) -> Result<(), BridgeError> {
        let Some(a) = self.arms.get_mut(arm) else {
            return Ok(());
        };
        let (t, header) = match s {
            Sample::Pose(t, p) => {
                a.encoder.pose(*t, p);
                (*t, &p.header)
            }
            Sample::PoseWithCovariance(t, p, cov) => {
                a.encoder.pose_with_covariance(*t, p, cov);
                (*t, &p.header)
            }
            Sample::Joints(t, js) => {
                a.encoder.joints(js);
                (*t, &js.header)
            }
            Sample::Jaw(t, jaw) => {
                a.encoder.jaw(jaw);
                (*t, &jaw.header)
            }
            Sample::Status(st) => {
                a.encoder.status(st);
                (OutTopic::Status, &st.header)
            }
        };
        let Some(channel_id) = OutTopic::RECORDED
            .iter()
            .position(|&x| x == t)
            .and_then(|i| a.channels[i])
        else {
            // A topic without a channel (raw while recording compensated only): not recorded.
            return Ok(());
        };
        let stamp = crate::convert::ros_time(header).as_unix_ns();
        let time = u64::try_from(stamp).unwrap_or(0);
        self.payload.clear();
        self.payload
            .extend_from_slice(&crate::cdr::ENCAPSULATION_CDR_LE);
        self.payload.extend_from_slice(a.encoder.last_body());
        let wrote = self.writer.write_to_known_channel(
            &MessageHeader {
                channel_id,
                sequence: header.seq as u32,
                log_time: time,
                publish_time: time,
            },
            &self.payload,
        );
        if let Err(source) = wrote {
            self.restore_footer();
            return Err(BridgeError::Mcap {
                path: self.path.clone(),
                source,
            });
        }
        a.written += 1;
        self.written += 1;
        self.chunk_bytes += self.payload.len() as u64;
        if self.chunk_bytes >= CLOSE_AT_BYTES || self.chunk_since.elapsed() >= CHUNK_INTERVAL {
            self.close_chunk()?;
        }
        Ok(())
    }
}
