/*
 * dvrk_ipc.h: message layouts of dvrk-sidecar for C and C++ consumers of iceoryx2 0.10.
 *
 * Mirrors crates/dvrk-ipc/src/msg.rs and flags.rs; the test crates/dvrk-ipc/tests/c_layout.rs
 * compiles a program against this header and compares every size and field offset with the
 * Rust types. Change both together, and bump the V<n> of the type name on any layout change:
 * iceoryx2 compares only the type name, size and alignment.
 *
 * Services, named as the dVRK 2.x console names its topics (prefix = the arm's name, default
 * "PSM1"; user header: none, i.e. Rust "()" of size 0, align 1):
 *   <prefix>/measured_js                    dvrk_JointStateV2  "dvrk::JointStateV2" (6 joints)
 *   <prefix>/jaw/measured_js                dvrk_JawStateV1    "dvrk::JawStateV1"
 *   <prefix>/local/measured_cp              dvrk_PoseV2        "dvrk::PoseV2" (RCM frame)
 *   <prefix>/measured_cp                    dvrk_PoseV2        (base frame)
 *   <prefix>/compensated/measured_js        dvrk_JointStateV2
 *   <prefix>/compensated/jaw/measured_js    dvrk_JawStateV1
 *   <prefix>/compensated/local/measured_cp  dvrk_PoseV2
 *   <prefix>/compensated/measured_cp        dvrk_PoseV2
 *   <prefix>/compensated/status             dvrk_CompensationStatusV4 "dvrk::CompensationStatusV4"
 *   <prefix>/cycle                          event, notified once per cycle after the nine messages
 *   <prefix>/cycle/first                    event, notified once per cycle right after its first
 *                                           message, compensated/local/measured_cp (the other
 *                                           eight are written after it): a consumer of that
 *                                           topic alone waits on this one to be woken sooner
 *
 * Open or create every service with the DVRK_IPC_QOS_* values below: whichever process creates
 * a service first fixes its QoS, and an opener that asks for more fails.
 *
 * Domain: the sidecar publishes in its account's own iceoryx2 domain, not iceoryx2's default
 * one. Set, in the iceoryx2 configuration of the consumer (it runs as the service's account):
 *   [global] root-path = "/tmp/dvrk-sidecar-<uid>/"  (or $DVRK_SIDECAR_IPC_ROOT when set)
 *            prefix    = "dvrk_<uid>_"
 * with <uid> the account's numeric uid (dvrk_ipc::default_domain in Rust).
 *
 * Units are SI (m, rad, N.m, N); *_t_ns are host CLOCK_MONOTONIC nanoseconds;
 * sample_realtime_ns is host CLOCK_REALTIME (ROS time) nanoseconds since the Unix epoch.
 */
#ifndef DVRK_IPC_H
#define DVRK_IPC_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
#define DVRK_IPC_STATIC_ASSERT(cond, msg) static_assert(cond, msg)
extern "C" {
#else
#define DVRK_IPC_STATIC_ASSERT(cond, msg) _Static_assert(cond, msg)
#endif

/* ---- services and QoS --------------------------------------------------------------------- */

#define DVRK_IPC_DEFAULT_PREFIX "PSM1"
#define DVRK_IPC_SUFFIX_MEASURED_JS "measured_js"
#define DVRK_IPC_SUFFIX_JAW_MEASURED_JS "jaw/measured_js"
#define DVRK_IPC_SUFFIX_LOCAL_MEASURED_CP "local/measured_cp"
#define DVRK_IPC_SUFFIX_MEASURED_CP "measured_cp"
#define DVRK_IPC_SUFFIX_COMPENSATED_MEASURED_JS "compensated/measured_js"
#define DVRK_IPC_SUFFIX_COMPENSATED_JAW_MEASURED_JS "compensated/jaw/measured_js"
#define DVRK_IPC_SUFFIX_COMPENSATED_LOCAL_MEASURED_CP "compensated/local/measured_cp"
#define DVRK_IPC_SUFFIX_COMPENSATED_MEASURED_CP "compensated/measured_cp"
#define DVRK_IPC_SUFFIX_COMPENSATED_STATUS "compensated/status"
#define DVRK_IPC_SUFFIX_CYCLE "cycle"
#define DVRK_IPC_SUFFIX_CYCLE_FIRST "cycle/first"

#define DVRK_IPC_QOS_MAX_PUBLISHERS 1
#define DVRK_IPC_QOS_MAX_SUBSCRIBERS 32
#define DVRK_IPC_QOS_SUBSCRIBER_MAX_BUFFER_SIZE 256
#define DVRK_IPC_QOS_SUBSCRIBER_MAX_BORROWED_SAMPLES 2
#define DVRK_IPC_QOS_HISTORY_SIZE 1
#define DVRK_IPC_QOS_ENABLE_SAFE_OVERFLOW 1
#define DVRK_IPC_QOS_MAX_NODES 36
#define DVRK_IPC_QOS_EVENT_MAX_NOTIFIERS 1
#define DVRK_IPC_QOS_EVENT_MAX_LISTENERS 32

/* Staleness (default of dvrk_ipc::Subscription): no sample for this many nominal periods, but at
 * least 10 ms (1500 Hz -> 666667 ns; a consumer may choose its own deadline). */
#define DVRK_IPC_DEADLINE_PERIODS 3
#define DVRK_IPC_NOMINAL_PERIOD_NS 666667

/* ---- type names (iceoryx2 payload type details) -------------------------------------------- */

#define DVRK_IPC_TYPE_NAME_JOINT_STATE_V2 "dvrk::JointStateV2"
#define DVRK_IPC_TYPE_NAME_JAW_STATE_V1 "dvrk::JawStateV1"
#define DVRK_IPC_TYPE_NAME_POSE_V2 "dvrk::PoseV2"
#define DVRK_IPC_TYPE_NAME_COMPENSATION_STATUS_V4 "dvrk::CompensationStatusV4"

/* ---- joints ---------------------------------------------------------------------------------- */

#define DVRK_IPC_NUM_JOINTS 6
/* Joint order: 0 yaw, 1 pitch, 2 insertion (m), 3 roll, 4 wrist_pitch, 5 wrist_yaw. */
#define DVRK_IPC_JOINT_NAMES {"yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw"}
/* The single joint of jaw/measured_js. */
#define DVRK_IPC_JAW_NAME "jaw"

/* ---- flags (dvrk_Header.flags) -------------------------------------------------------------- */

#define DVRK_IPC_FLAG_BOARD_TIMEOUT (1u << 0)        /* a board did not answer in time; valid = 0 */
#define DVRK_IPC_FLAG_BOARD_ERROR (1u << 1)          /* bad reply (CRC, label, length); valid = 0 */
#define DVRK_IPC_FLAG_WATCHDOG_TIMEOUT (1u << 2)     /* a board's watchdog expired */
#define DVRK_IPC_FLAG_POWER_OFF (1u << 3)            /* motor power off or supply not good */
#define DVRK_IPC_FLAG_ENCODER_ERROR (1u << 4)        /* encoder error or overflow */
#define DVRK_IPC_FLAG_AMP_FAULT (1u << 5)            /* amplifier fault or current-check trip */
#define DVRK_IPC_FLAG_INSERTION_CLAMPED (1u << 6)    /* model insertion clamped to its range */
#define DVRK_IPC_FLAG_CORRECTION_ACTIVE_J1 (1u << 7) /* compliance correction of joint 1 active */
#define DVRK_IPC_FLAG_CORRECTION_ACTIVE_J2 (1u << 8) /* compliance correction of joint 2 active */
#define DVRK_IPC_FLAG_SIMULATED (1u << 9)            /* source is the simulated PSM */
#define DVRK_IPC_FLAG_OVERRUN (1u << 10)             /* previous cycle exceeded the period */
#define DVRK_IPC_FLAG_IMPLAUSIBLE (1u << 11)         /* failed a plausibility check; valid = 0 */
#define DVRK_IPC_FLAG_NO_SOURCE (1u << 12)           /* tap sees no console traffic; valid = 0 */
#define DVRK_IPC_FLAG_HELD (1u << 13)                /* values held from the last valid sample */
#define DVRK_IPC_FLAG_NOT_HOMED (1u << 14) /* arm not homed (console); valid = 0 */
#define DVRK_IPC_FLAG_ARM_NOT_ENABLED (1u << 15) /* arm disabled/paused/fault: no correction */
#define DVRK_IPC_FLAG_CONSOLE_UNKNOWN (1u << 16) /* console not heard: configured values */
#define DVRK_IPC_FLAG_NO_INSTRUMENT (1u << 17) /* no instrument: compensated invalid */
#define DVRK_IPC_FLAG_INSTRUMENT_UNSUPPORTED (1u << 18) /* instrument not modelled: compensated invalid */
#define DVRK_IPC_FLAG_NO_CALIBRATION (1u << 19) /* no parameters for it: compensated = raw */
#define DVRK_IPC_FLAG_BASE_FRAME_STALE (1u << 20) /* console base frame older than 1 s */
#define DVRK_IPC_FLAG_WARMUP (1u << 21) /* estimator warming up */
#define DVRK_IPC_FLAG_GAP (1u << 22) /* gap restarted the estimator */
#define DVRK_IPC_FLAG_TRANSIENT (1u << 23) /* abrupt change: correction held back */
#define DVRK_IPC_FLAG_ACCEL_OUT_OF_RANGE (1u << 24) /* acceleration beyond the fit */
#define DVRK_IPC_FLAG_INSERTION_EXTRAPOLATED (1u << 25) /* insertion extrapolated */
#define DVRK_IPC_FLAG_INSERTION_OUT_OF_RANGE (1u << 26) /* insertion out of range: no correction */
#define DVRK_IPC_FLAG_STILL_ONLY (1u << 27) /* no dynamics model: only while still */
#define DVRK_IPC_FLAG_REDUCED (1u << 28) /* correction less than the model's */
#define DVRK_IPC_FLAG_POT_MISMATCH (1u << 29) /* refused: a pot and its encoder disagree (slipped encoder?) */
#define DVRK_IPC_FLAG_POSITION_OUT_OF_RANGE (1u << 30) /* joint 1/2 outside its torque-offset table: correction faded, none beyond 0.05 rad */
#define DVRK_IPC_FLAG_FAULT_MASK (0x3fu)             /* bits 0..5 */

/* ---- messages -------------------------------------------------------------------------------- */

/* Common header. seq is equal in all nine messages of a cycle. sample_realtime_ns is the
 * CLOCK_REALTIME (ROS) time of the same instant as sample_t_ns. board_timestamp: first board's
 * counter in the low 32 bits, second board's in the high 32 bits. valid: 1 or 0. */
typedef struct dvrk_Header {
    uint64_t seq;
    uint64_t sample_t_ns;
    uint64_t sample_realtime_ns;
    uint64_t board_timestamp;
    uint64_t publish_t_ns;
    uint32_t valid;
    uint32_t flags;
} dvrk_Header;

/* Joint state: position (rad; m for insertion), velocity, effort (N.m; N for insertion). */
typedef struct dvrk_JointStateV2 {
#ifdef __cplusplus
    static constexpr const char* IOX2_TYPE_NAME = DVRK_IPC_TYPE_NAME_JOINT_STATE_V2;
#endif
    dvrk_Header header;
    double position[DVRK_IPC_NUM_JOINTS];
    double velocity[DVRK_IPC_NUM_JOINTS];
    double effort[DVRK_IPC_NUM_JOINTS];
} dvrk_JointStateV2;

/* Jaw state (jaw/measured_js): opening (rad), its rate (rad/s), effort (N.m). */
typedef struct dvrk_JawStateV1 {
#ifdef __cplusplus
    static constexpr const char* IOX2_TYPE_NAME = DVRK_IPC_TYPE_NAME_JAW_STATE_V1;
#endif
    dvrk_Header header;
    double position;
    double velocity;
    double effort;
} dvrk_JawStateV1;

/* Tool-tip pose: in the RCM frame on local/measured_cp, in the base frame on measured_cp.
 * rotation is row-major 3x3: rotation[3 * row + col]; orientation_xyzw is the same rotation as
 * a unit quaternion. */
typedef struct dvrk_PoseV2 {
#ifdef __cplusplus
    static constexpr const char* IOX2_TYPE_NAME = DVRK_IPC_TYPE_NAME_POSE_V2;
#endif
    dvrk_Header header;
    double position_m[3];
    double orientation_xyzw[4];
    double rotation[9];
} dvrk_PoseV2;

/* Compensation and loop status. delta_rad = q - q_hat of joints 1, 2; *_total are counters since
 * the publisher started; cycle_duration_ns is the most recent completed cycle's work time. */
typedef struct dvrk_CompensationStatusV4 {
#ifdef __cplusplus
    static constexpr const char* IOX2_TYPE_NAME = DVRK_IPC_TYPE_NAME_COMPENSATION_STATUS_V4;
#endif
    dvrk_Header header;
    double tau_ext_nm[2];
    double delta_rad[2];
    double insertion_m;
    uint64_t cycle_period_ns;
    uint64_t cycle_duration_ns;
    uint64_t cycles_total;
    uint64_t read_failures_total;
    uint64_t overruns_total;
    uint32_t consecutive_read_failures;
    uint32_t source_state;        /* console state, parameter set, instrument (see msg.rs) */
    double tau_margin_nm[2];      /* |tau_ext| minus the engage threshold, joints 1, 2 (N.m) */
    uint64_t held_sample_age_ns;  /* 0 when fresh; age of the held valid sample otherwise */
    uint64_t publish_late_ns;     /* how late the cycle started after its deadline */
    uint64_t implausible_total;   /* samples rejected by the plausibility checks */
    double bound_rad[2];          /* 95% bound on the compensated joints 1, 2 error (rad) */
    double tip_bound_m;           /* 95% bound on the compensated tip position error (m) */
    double weight[2];             /* share of the model's correction applied, joints 1, 2 */
    uint64_t _reserved;
} dvrk_CompensationStatusV4;

/* ---- layout checks (the same numbers as the Rust const assertions) --------------------------- */

DVRK_IPC_STATIC_ASSERT(sizeof(double) == 8, "double must be IEEE 754 binary64");
DVRK_IPC_STATIC_ASSERT(sizeof(dvrk_Header) == 48, "dvrk_Header size");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_Header, sample_realtime_ns) == 16, "dvrk_Header.sample_realtime_ns offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_Header, valid) == 40, "dvrk_Header.valid offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_Header, flags) == 44, "dvrk_Header.flags offset");

DVRK_IPC_STATIC_ASSERT(sizeof(dvrk_JointStateV2) == 192, "dvrk_JointStateV2 size");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_JointStateV2, position) == 48, "position offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_JointStateV2, velocity) == 96, "velocity offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_JointStateV2, effort) == 144, "effort offset");

DVRK_IPC_STATIC_ASSERT(sizeof(dvrk_JawStateV1) == 72, "dvrk_JawStateV1 size");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_JawStateV1, position) == 48, "jaw position offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_JawStateV1, effort) == 64, "jaw effort offset");

DVRK_IPC_STATIC_ASSERT(sizeof(dvrk_PoseV2) == 176, "dvrk_PoseV2 size");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_PoseV2, position_m) == 48, "position_m offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_PoseV2, orientation_xyzw) == 72, "orientation offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_PoseV2, rotation) == 104, "rotation offset");

DVRK_IPC_STATIC_ASSERT(sizeof(dvrk_CompensationStatusV4) == 224, "dvrk_CompensationStatusV4 size");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_CompensationStatusV4, tip_bound_m) == 192, "tip_bound_m offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_CompensationStatusV4, insertion_m) == 80, "insertion_m offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_CompensationStatusV4, consecutive_read_failures) == 128,
                       "consecutive_read_failures offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_CompensationStatusV4, tau_margin_nm) == 136, "tau_margin_nm offset");
DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_CompensationStatusV4, implausible_total) == 168,
                       "implausible_total offset");

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* DVRK_IPC_H */
