//! The MCAP shell: writes the bridge's topics to an MCAP file with `ros2msg` schemas and CDR
//! payloads, the layout `ros2 bag` (rosbag2_storage_mcap), Foxglove and PlotJuggler read.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use dvrk_ipc::{CompensationStatusV2, JointStateV1, PoseV1};
use mcap::records::MessageHeader;

use crate::convert::{Encoder, OutTopic};
use crate::error::BridgeError;
use crate::source::Sink;

/// An MCAP file being written: one channel per [`OutTopic`], named by its ROS 2 topic name
/// (`/PSM1/compensated/local/measured_cp`).
///
/// Log and publish times are the message's ROS stamp (the sample time in CLOCK_REALTIME ns), and
/// the MCAP sequence is the low 32 bits of the sidecar's `seq`.
pub struct McapSink {
    encoder: Encoder,
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    channels: [u16; OutTopic::ALL.len()],
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
    /// Creates (or truncates) `path` and registers the schemas and channels.
    pub fn create(encoder: Encoder, path: &Path) -> Result<Self, BridgeError> {
        let file = File::create(path).map_err(|source| BridgeError::CreateFile {
            path: path.to_owned(),
            source,
        })?;
        let mcap_err = |source| BridgeError::Mcap {
            path: path.to_owned(),
            source,
        };
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .create(BufWriter::new(file))
            .map_err(mcap_err)?;
        let mut channels = [0u16; OutTopic::ALL.len()];
        for (i, t) in OutTopic::ALL.into_iter().enumerate() {
            let ty = t.msg_type();
            let schema = writer
                .add_schema(ty.ros_name, "ros2msg", ty.schema.as_bytes())
                .map_err(mcap_err)?;
            channels[i] = writer
                .add_channel(
                    schema,
                    &t.ros_name(&encoder.frames.arm),
                    "cdr",
                    &BTreeMap::new(),
                )
                .map_err(mcap_err)?;
        }
        Ok(McapSink {
            encoder,
            path: path.to_owned(),
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

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<u64, BridgeError> {
        self.writer.finish().map_err(|source| BridgeError::Mcap {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.written)
    }

    fn write(&mut self, t: OutTopic, header: &dvrk_ipc::Header) -> Result<(), BridgeError> {
        let i = OutTopic::ALL.iter().position(|&x| x == t).unwrap_or(0);
        let stamp = self.encoder.stamp(header).as_unix_ns();
        let time = u64::try_from(stamp).unwrap_or(0);
        self.payload.clear();
        self.payload
            .extend_from_slice(&crate::cdr::ENCAPSULATION_CDR_LE);
        self.payload.extend_from_slice(self.encoder.last_body());
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id: self.channels[i],
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
        Ok(())
    }
}

impl Sink for McapSink {
    fn pose(&mut self, p: &PoseV1) -> Result<(), BridgeError> {
        for t in [OutTopic::LocalMeasuredCp, OutTopic::MeasuredCp] {
            self.encoder.pose(t, p);
            self.write(t, &p.header)?;
        }
        Ok(())
    }

    fn joints(&mut self, js: &JointStateV1) -> Result<(), BridgeError> {
        for t in [OutTopic::MeasuredJs, OutTopic::JawMeasuredJs] {
            self.encoder.joints(t, js);
            self.write(t, &js.header)?;
        }
        Ok(())
    }

    fn status(&mut self, s: &CompensationStatusV2) -> Result<(), BridgeError> {
        self.encoder.status(s);
        self.write(OutTopic::Status, &s.header)
    }
}
