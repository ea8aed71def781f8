//! The MCAP shell: writes the bridge's topics to an MCAP file with `ros2msg` schemas and CDR
//! payloads, the layout `ros2 bag` (rosbag2_storage_mcap), Foxglove and PlotJuggler read.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use dvrk_ipc::{CompensationStatusV4, JawStateV1, JointStateV2, PoseV2};
use mcap::records::MessageHeader;

use crate::convert::{Encoder, OutTopic};
use crate::error::BridgeError;
use crate::source::Sink;

/// An MCAP file being written: one channel per recorded [`OutTopic`], named by its ROS 2 topic
/// name (`/PSM1/compensated/local/measured_cp`, `/PSM1/measured_js`).
///
/// The file is written as `.<name>.partial` beside the target and renamed to it by
/// [`McapSink::finish`], so a reader never sees a file without its summary; [`McapSink::abandon`]
/// removes it after an error.
///
/// Log and publish times are the message's ROS stamp (the sample time in CLOCK_REALTIME ns), and
/// the MCAP sequence is the low 32 bits of the sidecar's `seq`.
pub struct McapSink {
    encoder: Encoder,
    path: PathBuf,
    tmp: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
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
        let Some(name) = path.file_name() else {
            return Err(BridgeError::InvalidArgument {
                what: "--out",
                value: path.display().to_string(),
                reason: "not a file path",
            });
        };
        let tmp = path.with_file_name(format!(".{}.partial", name.to_string_lossy()));
        let file = File::create(&tmp).map_err(|source| BridgeError::CreateFile {
            path: tmp.clone(),
            source,
        })?;
        let mcap_err = |source| BridgeError::Mcap {
            path: tmp.clone(),
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
        Ok(McapSink {
            encoder,
            path: path.to_owned(),
            tmp,
            writer,
            channels,
            payload: Vec::new(),
            written: 0,
        })
    }

    /// Messages written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Writes the summary, closes the file and renames it to its target; returns the number of
    /// messages. On error the partial file is removed.
    pub fn finish(mut self) -> Result<u64, BridgeError> {
        let tmp = self.tmp.clone();
        let result = self
            .writer
            .finish()
            .map_err(|source| BridgeError::Mcap {
                path: tmp.clone(),
                source,
            })
            .and_then(|_| {
                self.writer
                    .into_inner()
                    .into_inner()
                    .map_err(|e| BridgeError::CreateFile {
                        path: tmp.clone(),
                        source: e.into_error(),
                    })
            })
            .and_then(|file| {
                file.sync_all().map_err(|source| BridgeError::CreateFile {
                    path: tmp.clone(),
                    source,
                })
            })
            .and_then(|()| {
                std::fs::rename(&tmp, &self.path).map_err(|source| BridgeError::CreateFile {
                    path: self.path.clone(),
                    source,
                })
            });
        match result {
            Ok(()) => Ok(self.written),
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }

    /// Removes the partial file (after an error).
    pub fn abandon(self) {
        let tmp = self.tmp.clone();
        drop(self);
        let _ = std::fs::remove_file(tmp);
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
                path: self.tmp.clone(),
                source,
            })?;
        self.written += 1;
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
