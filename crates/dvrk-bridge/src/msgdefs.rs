//! The ROS 2 message types the bridge writes: their ROS names, DDS type names and `ros2msg`
//! definitions (the schema text MCAP readers such as Foxglove, PlotJuggler and `ros2 bag` use to
//! decode the CDR payloads).
//!
//! A `ros2msg` schema is the message's own definition followed by the definition of every type it
//! uses, each introduced by a line of 80 `=` and a `MSG: package/Type` line.

/// One message type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MsgType {
    /// ROS name, e.g. `geometry_msgs/msg/PoseStamped`.
    pub ros_name: &'static str,
    /// DDS type name as the ROS 2 rmw layers register it.
    pub dds_name: &'static str,
    /// `ros2msg` schema text (with dependencies).
    pub schema: &'static str,
}

macro_rules! sep {
    ($name:literal) => {
        concat!(
            "\n================================================================================\nMSG: ",
            $name,
            "\n"
        )
    };
}

/// The header block, spelled out inside each schema (concat! takes literals only); a test keeps
/// the copies identical.
#[cfg(test)]
const HEADER: &str = concat!(
    sep!("std_msgs/Header"),
    "builtin_interfaces/Time stamp\nstring frame_id\n",
    sep!("builtin_interfaces/Time"),
    "int32 sec\nuint32 nanosec\n"
);

/// `geometry_msgs/PoseStamped`.
pub const POSE_STAMPED: MsgType = MsgType {
    ros_name: "geometry_msgs/msg/PoseStamped",
    dds_name: "geometry_msgs::msg::dds_::PoseStamped_",
    schema: concat!(
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
        sep!("std_msgs/Header"),
        "builtin_interfaces/Time stamp\nstring frame_id\n",
        sep!("builtin_interfaces/Time"),
        "int32 sec\nuint32 nanosec\n",
        sep!("geometry_msgs/Pose"),
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
        sep!("geometry_msgs/Point"),
        "float64 x\nfloat64 y\nfloat64 z\n",
        sep!("geometry_msgs/Quaternion"),
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
    ),
};

/// `geometry_msgs/PoseWithCovarianceStamped`: the compensated pose with the covariance of its
/// error (see [`crate::convert::PoseCovariance`]).
pub const POSE_WITH_COVARIANCE_STAMPED: MsgType = MsgType {
    ros_name: "geometry_msgs/msg/PoseWithCovarianceStamped",
    dds_name: "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_",
    schema: concat!(
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n",
        sep!("std_msgs/Header"),
        "builtin_interfaces/Time stamp\nstring frame_id\n",
        sep!("builtin_interfaces/Time"),
        "int32 sec\nuint32 nanosec\n",
        sep!("geometry_msgs/PoseWithCovariance"),
        "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
        sep!("geometry_msgs/Pose"),
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
        sep!("geometry_msgs/Point"),
        "float64 x\nfloat64 y\nfloat64 z\n",
        sep!("geometry_msgs/Quaternion"),
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
    ),
};

/// `sensor_msgs/JointState`.
pub const JOINT_STATE: MsgType = MsgType {
    ros_name: "sensor_msgs/msg/JointState",
    dds_name: "sensor_msgs::msg::dds_::JointState_",
    schema: concat!(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
        sep!("std_msgs/Header"),
        "builtin_interfaces/Time stamp\nstring frame_id\n",
        sep!("builtin_interfaces/Time"),
        "int32 sec\nuint32 nanosec\n"
    ),
};

/// `dvrk_sidecar_msgs/CompensationStatus`: the sidecar's `compensated/status`. No ROS package
/// defines it yet: MCAP readers decode it from the schema below; a ROS 2 node needs an interface
/// package with this definition to subscribe.
pub const COMPENSATION_STATUS: MsgType = MsgType {
    ros_name: "dvrk_sidecar_msgs/msg/CompensationStatus",
    dds_name: "dvrk_sidecar_msgs::msg::dds_::CompensationStatus_",
    schema: concat!(
        "# State of the compliance compensation of dvrk-sidecar and of its publishing loop.\n",
        "std_msgs/Header header\n",
        "uint64 seq\n",
        "bool valid\n",
        "uint32 flags\n",
        "float64[2] tau_ext_nm\n",
        "float64[2] delta_rad\n",
        "float64 insertion_m\n",
        "float64[2] tau_margin_nm\n",
        "uint64 cycle_period_ns\n",
        "uint64 cycle_duration_ns\n",
        "uint64 cycles_total\n",
        "uint64 read_failures_total\n",
        "uint64 overruns_total\n",
        "uint32 consecutive_read_failures\n",
        "uint64 held_sample_age_ns\n",
        "uint64 publish_late_ns\n",
        "uint64 implausible_total\n",
        "# What produced the sample: console state, homed, parameter set, instrument (see the sidecar's\n",
        "# dvrk-ipc msg.rs, CompensationStatusV4::source_state).\n",
        "uint32 source_state\n",
        "# 95% bounds on the error of the compensated joints 1, 2 (rad) and tip position (m).\n",
        "float64[2] bound_rad\n",
        "float64 tip_bound_m\n",
        "# Share of the model's correction applied to joints 1, 2 (0 to 1).\n",
        "float64[2] weight\n",
        sep!("std_msgs/Header"),
        "builtin_interfaces/Time stamp\nstring frame_id\n",
        sep!("builtin_interfaces/Time"),
        "int32 sec\nuint32 nanosec\n"
    ),
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_embed_the_shared_header_block() {
        for t in [
            POSE_STAMPED,
            POSE_WITH_COVARIANCE_STAMPED,
            JOINT_STATE,
            COMPENSATION_STATUS,
        ] {
            assert!(t.schema.contains(HEADER), "{}", t.ros_name);
            assert!(t.schema.starts_with("std_msgs/Header header\n") || t.schema.starts_with('#'));
        }
    }

    #[test]
    fn the_pose_with_covariance_defines_the_pose_as_pose_stamped_does() {
        let pose = |schema: &'static str| {
            let at = schema.find("MSG: geometry_msgs/Pose\n").unwrap();
            &schema[at..]
        };
        assert_eq!(
            pose(POSE_WITH_COVARIANCE_STAMPED.schema),
            pose(POSE_STAMPED.schema)
        );
        assert!(
            POSE_WITH_COVARIANCE_STAMPED
                .schema
                .contains("MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n")
        );
    }

    #[test]
    fn dds_names_follow_the_rmw_convention() {
        for t in [
            POSE_STAMPED,
            POSE_WITH_COVARIANCE_STAMPED,
            JOINT_STATE,
            COMPENSATION_STATUS,
        ] {
            let mut parts = t.ros_name.split('/');
            let (pkg, msg, ty) = (
                parts.next().unwrap(),
                parts.next().unwrap(),
                parts.next().unwrap(),
            );
            assert_eq!(t.dds_name, format!("{pkg}::{msg}::dds_::{ty}_"));
        }
    }

    #[test]
    fn the_ros2_interface_package_defines_the_same_status() {
        // ros2/dvrk_sidecar_msgs, for labs that build it in their colcon workspace.
        let file = include_str!("../../../ros2/dvrk_sidecar_msgs/msg/CompensationStatus.msg");
        let own = COMPENSATION_STATUS
            .schema
            .split("\n====")
            .next()
            .unwrap_or_default();
        assert_eq!(file.trim_end(), own.trim_end());
    }
}
