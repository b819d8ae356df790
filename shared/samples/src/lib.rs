//! The live stack's vocabulary: one `#[repr(C)]` plain-data type per
//! service, and every service name. Fields are ordered largest first (all
//! 8-byte values, then the 4-byte flags and codes) so there is no hidden
//! padding; a test checks each size.
//!
//! Every sample carries `sensor_seq` and `sensor_time_ns`, the sequence
//! number and timestamp of the sensor reading it derives from, and
//! `stage_time_ns`, when its own stage published it, so latency and
//! causality are read from the data. Times are CLOCK_MONOTONIC nanoseconds,
//! shared by every process on the machine.
//!
//! What it holds: Every `#[repr(C)]` sample type (iceoryx2 `ZeroCopySend`,
//! `bytemuck::Pod`) and every service name. Each sample carries its sensor
//! reading's sequence number and timestamp and its own stage's timestamp.
//! `schema`: each type's `ros2msg` schema and where its sequence and
//! timestamp sit (and which fields are text), `cdr`: the CDR encoding of a
//! sample with text, its NUL-padded fields as ROS 2 strings and back, the
//! stack's services with their types, and `visit_kind`, the one place where a
//! type name read at run time becomes a Rust type.

use bytemuck::{Pod, Zeroable};
use iceoryx2::prelude::*;

pub mod cdr;
mod schema;
pub use schema::{visit_kind, KindVisitor, Recordable, SampleKind, CDR_HEADER, KINDS, STACK_SERVICES};

/// Service names. A sample of the loop's own services
/// ([`service::PIPELINE_SERVICES`]) rings the service's doorbell, a futex in
/// the run's shared memory, for the stage that waits for it; every other
/// publish-subscribe service has an event service of the same name,
/// notified after every sample.
pub mod service {
    /// The loop's processes in pipeline order: the plant, then the stages.
    /// Each publishes the service at its place in [`PIPELINE_SERVICES`].
    pub const PIPELINE_PROCESSES: [&str; 6] = ["plant", "sensor", "friction", "position", "torque", "valve"];

    /// The loop's stages: every process of the pipeline but the plant.
    pub const STAGES: &[&str] = PIPELINE_PROCESSES.split_at(1).1;

    /// The loop's services, from the plant's reading to the valve's state:
    /// the stage waiting for each sleeps on its doorbell.
    pub const PIPELINE_SERVICES: [&str; 6] = [PLANT_READING, SENSOR, FRICTION, POSITION, TORQUE, VALVE];

    /// Whether a sample of `name` wakes its reader by a doorbell (else by
    /// an iceoryx2 event).
    pub fn rings_doorbell(name: &str) -> bool {
        PIPELINE_SERVICES.contains(&name)
    }

    /// The plant's raw readings: the simulated sensor bus.
    pub const PLANT_READING: &str = "hydractl/plant/reading";
    pub const SENSOR: &str = "hydractl/sensor";
    pub const FRICTION: &str = "hydractl/friction";
    pub const POSITION: &str = "hydractl/position";
    pub const TORQUE: &str = "hydractl/torque";
    /// The valve's state: the command it drives, and its faults.
    pub const VALVE: &str = "hydractl/valve";
    /// The machine's valve device (on CAN): its state and latched fault.
    pub const VALVE_DEVICE: &str = "hydractl/valve/device";
    /// Requests to the valve process (request-response): a fault reset.
    pub const VALVE_COMMAND: &str = "hydractl/valve/command";
    /// The supervisor's view of every process.
    pub const SUPERVISOR_STATUS: &str = "hydractl/supervisor/status";
    /// The recorder's progress: messages written, samples missed, files.
    pub const RECORDER_STATUS: &str = "hydractl/recorder/status";
    /// Requests to the supervisor (request-response): swap a controller.
    pub const SUPERVISOR_COMMAND: &str = "hydractl/supervisor/command";
    /// What the supervisor did: swaps, faults and what it did about them.
    pub const SUPERVISOR_EVENTS: &str = "hydractl/supervisor/events";
    /// The cycle at which a standby controller takes over from the running one.
    pub const HANDOVER: &str = "hydractl/control/handover";
    /// Each process named by a handover says it read it.
    pub const HANDOVER_ACK: &str = "hydractl/control/handover/ack";
    /// A standby controller's outputs while it tracks the running one.
    pub const POSITION_STANDBY: &str = "hydractl/position/standby";
    pub const TORQUE_STANDBY: &str = "hydractl/torque/standby";
    /// The machine's readings while the simulated plant drives the loop:
    /// it is alive, and the loop can go back to it.
    pub const PLANT_STANDBY: &str = "hydractl/plant/standby";
    /// The shadow model's fit of the machine over its last window.
    pub const SHADOW: &str = "hydractl/shadow";
    /// The shadow's drift alarms, and what changed once it is named.
    pub const SHADOW_DRIFT: &str = "hydractl/shadow/drift";
    /// The virtual CAN bus `interface`: frames handed to the wire.
    pub fn can_tx(interface: &str) -> String {
        format!("hydractl/can/{interface}/tx")
    }
    /// The virtual CAN bus `interface`: its wire's counters.
    pub fn can_wire(interface: &str) -> String {
        format!("hydractl/can/{interface}/wire")
    }
    /// The virtual CAN bus `interface`: frames that crossed it, to every station.
    pub fn can_rx(interface: &str) -> String {
        format!("hydractl/can/{interface}/rx")
    }

    /// The interface whose received frames `name` carries, if it is a
    /// [`can_rx`] service.
    pub fn can_rx_interface(name: &str) -> Option<&str> {
        name.strip_prefix("hydractl/can/")?.strip_suffix("/rx")
    }
}

/// Where a reading comes from: the machine, or the simulated plant. Zero,
/// a sample's default, says simulation: nothing claims to be the machine
/// unless the machine made it.
pub mod source {
    pub const SIMULATION: u32 = 0;
    pub const MACHINE: u32 = 1;

    pub fn name(source: u32) -> &'static str {
        match source {
            MACHINE => "machine",
            _ => "simulation",
        }
    }
}

/// Validity flags of a sensor sample.
pub mod valid {
    pub const ANGLE: u32 = 1 << 0;
    pub const PRESSURE_A: u32 = 1 << 1;
    pub const PRESSURE_B: u32 = 1 << 2;
    pub const ALL: u32 = ANGLE | PRESSURE_A | PRESSURE_B;
}

/// Fault flags of the valve's state.
pub mod fault;

/// Codes of the structure and variants, for samples that report them.
pub mod code;

/// One CAN frame on the virtual bus. A station submits it on
/// [`service::can_tx`]; the bus process delivers it to every station on
/// [`service::can_rx`] once it has crossed the wire.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::CanFrameSample")]
pub struct CanFrameSample {
    /// Delivered: the bus's count of frames; submitted: the station's.
    pub seq: u64,
    /// Delivered: when the frame's last bit left the wire; submitted:
    /// when it was handed over, ns.
    pub time_ns: u64,
    pub submitted_ns: u64,
    /// Who sent it: the sending process's pid.
    pub station: u32,
    /// [`hydractl_can::Frame`]'s fields.
    pub id: u32,
    pub flags: u8,
    pub len: u8,
    pub reserved: [u8; 6],
    pub data: [u8; 8],
}

/// The virtual CAN bus's wire, as its own counters say: published every
/// 100 ms and when it stops.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::WireStatus")]
pub struct WireStatus {
    pub seq: u64,
    pub stage_time_ns: u64,
    /// Frames that crossed the wire.
    pub delivered: u64,
    /// Frames lost: a full transmit queue, or handed over while bus-off.
    pub lost: u64,
    /// Frames of silenced stations, never sent.
    pub silenced: u64,
    pub error_frames: u64,
    /// Bus time used, ns.
    pub busy_ns: u64,
    /// Since the last status: the most a frame was delivered after its
    /// last bit crossed, ns, and when that bit crossed. The wire's own
    /// timer runs on the loop's CPU at the loop's priority: late, the CPU
    /// was kept from the loop (by the host, or by a task that spins).
    pub late_max_ns: u64,
    pub late_max_due_ns: u64,
    /// Since the wire started: its wake-ups that delivered a frame 0.1 ms
    /// or more after its time, and the latest any frame came, ns.
    pub late_wakeups: u64,
    pub late_worst_ns: u64,
}

/// What the plant's sensors read (on the vehicle: what arrives on the bus).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::PlantReading")]
pub struct PlantReading {
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    /// Encoder angle, rad.
    pub angle: f64,
    /// Chamber pressures, Pa.
    pub p_a: f64,
    pub p_b: f64,
    /// The plant's true angle, rad: for monitoring only, never for control.
    pub true_angle: f64,
    /// Periods in which the valve command arrived too late to be applied.
    pub late_commands: u64,
    /// [`source`]: the machine or the simulated plant.
    pub source: u32,
    /// Periods for which the valve's own timeout (the amplifier's watchdog,
    /// on the vehicle the valve's RPDO timeout) has held it neutral: no
    /// command for longer than the guard allows. 0 while commands come.
    pub amplifier_neutral_for: u32,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::SensorSample")]
pub struct SensorSample {
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    pub angle: f64,
    /// Differentiated and low-pass filtered, rad/s.
    pub velocity: f64,
    pub p_a: f64,
    pub p_b: f64,
    /// D (p_a − p_b), N·m.
    pub torque: f64,
    /// [`valid`] flags.
    pub valid: u32,
    /// [`source`] of the reading.
    pub source: u32,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::FrictionSample")]
pub struct FrictionSample {
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    /// Valve command units.
    pub compensation: f64,
    /// The blended velocity of the crane paper's eq. (1), rad/s.
    pub blended_velocity: f64,
    /// The load's feed-forward (Coulomb friction, gravity) in the outer
    /// loop's output units: N·m in the cascade, valve command otherwise.
    pub load_feedforward: f64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::PositionSample")]
pub struct PositionSample {
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    pub reference_angle: f64,
    pub reference_velocity: f64,
    pub reference_acceleration: f64,
    /// The measured angle the output was computed from, rad.
    pub angle: f64,
    /// Valve command (position-only) or torque reference, N·m (cascade).
    pub output: f64,
    /// [`code`] of the structure and of the variant in charge.
    pub structure: u32,
    pub variant: u32,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::TorqueSample")]
pub struct TorqueSample {
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    pub torque_reference: f64,
    pub torque: f64,
    /// Valve command before shaping.
    pub command: f64,
    pub variant: u32,
    pub reserved: u32,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::ValveSample")]
pub struct ValveSample {
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    /// The command driven into the valve, [-1, 1]; 0 (neutral) on a fault.
    pub command: f64,
    /// What the upstream stage asked for.
    pub requested: f64,
    /// [`fault`] flags; 0 when healthy.
    pub faults: u32,
    /// The [`code`] variant of the controller whose command this answers
    /// (the torque sample's), for judging who is in charge.
    pub variant: u32,
}

/// One process as the supervisor sees it.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::ProcessStatus")]
pub struct ProcessStatus {
    /// NUL-padded ASCII.
    pub name: [u8; 16],
    pub variant: [u8; 16],
    pub pid: u32,
    pub restarts: u32,
    /// 1 when running and producing output.
    pub healthy: u32,
    /// A loop process: page faults since it answered its first reading
    /// (the goal is none); [`UNKNOWN`] for a process with no loop, or one
    /// that has not answered yet.
    pub page_faults_after_start: u32,
    /// 1 when its memory is locked (`mlockall`: `timing.lock_memory`).
    pub memory_locked: u32,
}

/// A count not known.
pub const UNKNOWN: u32 = u32::MAX;

pub const MAX_PROCESSES: usize = 12;

#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::SupervisorStatus")]
pub struct SupervisorStatus {
    /// Counts the statuses published, so a recording shows a lost one.
    pub seq: u64,
    pub stage_time_ns: u64,
    pub processes: [ProcessStatus; MAX_PROCESSES],
    pub process_count: u32,
    /// 0: the machine (or its stand-in), 1: the simulated plant.
    pub plant_is_simulation: u32,
}

/// From the supervisor to the controllers: at `at_seq`, the process
/// `new_pid` takes over `stage` and the one running stops publishing.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::Handover")]
pub struct Handover {
    pub seq: u64,
    pub stage_time_ns: u64,
    /// The first sensor reading the new process answers.
    pub at_seq: u64,
    pub new_pid: u32,
    /// [`code`] stage and variant.
    pub stage: u32,
    pub variant: u32,
    pub reserved: u32,
}

/// From a process to the supervisor: it read handover `handover_seq` and
/// will act on it at `at_seq`, taking over (`taking` 1) or retiring (0).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::HandoverAck")]
pub struct HandoverAck {
    pub handover_seq: u64,
    pub stage_time_ns: u64,
    pub at_seq: u64,
    pub pid: u32,
    pub taking: u32,
}

/// Something the supervisor saw and what it did: a swap, a fault.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::SupervisorEvent")]
pub struct SupervisorEvent {
    pub seq: u64,
    pub stage_time_ns: u64,
    /// Swap: the handover's reading. Fault: the last reading the process
    /// answered.
    pub sensor_seq: u64,
    /// Valve periods without a fresh command around the event.
    pub missed_cycles: u64,
    /// Swap: the valve command's largest step from the switch through its
    /// transient (5 readings), as a fraction of its range [-1, 1].
    pub command_step: f64,
    /// Swap: the largest such step of the loop's own, in the second before
    /// the switch (old controller) and after its transient (new one).
    pub loop_step_before: f64,
    pub loop_step_after: f64,
    /// Fallback judged: the tracking error's rms (rad) before the fault
    /// and over the watched window after the restart.
    pub tracking_rms_before_rad: f64,
    pub tracking_rms_after_rad: f64,
    /// Fault: periods from the first missed deadline (the command for the
    /// reading after the last one answered, due one period later) to the
    /// valve's neutral; the valve holds its last command meanwhile
    /// (u64::MAX: the valve never needed to be made safe).
    pub valve_safe_after_periods: u64,
    /// Fault: from the process's last output to the supervisor seeing it.
    pub detected_after_ns: u64,
    /// Fault: from the detection to the new process's first output.
    pub restarted_after_ns: u64,
    /// [`code::EventKind::code`].
    pub kind: u32,
    pub pid: u32,
    /// NUL-padded ASCII: the process (or stage), and the variants.
    pub process: [u8; 16],
    pub from: [u8; 16],
    pub to: [u8; 16],
}

/// The machine's valve device as the valve process sees it (CAN only):
/// published when it changes and every 100 ms.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::ValveDevice")]
pub struct ValveDevice {
    pub seq: u64,
    pub stage_time_ns: u64,
    /// When the latched fault was first seen, ns since the Unix epoch (it
    /// may predate this run); 0 without one.
    pub latched_since_unix_ns: u64,
    /// The last reset by this valve process, CLOCK_MONOTONIC ns; 0: none.
    pub reset_time_ns: u64,
    /// The latched fault's code: the EMCY's error code, or the stack's own
    /// (above 0xFFFF); 0 without one.
    pub fault_code: u32,
    pub latched: u32,
    /// Resets by this valve process.
    pub resets: u32,
    pub reserved: u32,
    /// NUL-padded UTF-8: the device's state in words ("active", "fault
    /// hold", "not heard"), and the latched fault's meaning.
    pub state: [u8; 16],
    pub meaning: [u8; 128],
}

impl Default for ValveDevice {
    fn default() -> Self {
        Self::zeroed()
    }
}

/// A request to the valve process.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("hydractl::ValveRequest")]
pub struct ValveRequest {
    /// [`code`] `VALVE_*`.
    pub kind: u32,
    /// Reset: 1 when a person says the valve was serviced (the count of
    /// recent resets starts again).
    pub serviced: u32,
}

/// A request to the supervisor.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("hydractl::SupervisorRequest")]
pub struct SupervisorRequest {
    /// [`code`] stage and variant to swap to.
    pub stage: u32,
    pub variant: u32,
}

/// The supervisor's answer, once the swap is done or has failed.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("hydractl::SupervisorReply")]
pub struct SupervisorReply {
    pub command_step: f64,
    pub missed_cycles: u64,
    pub accepted: u32,
    pub from_variant: u32,
    /// NUL-padded UTF-8: what happened, in words.
    pub message: [u8; 320],
}

impl Default for SupervisorReply {
    fn default() -> Self {
        Self {
            command_step: 0.0,
            missed_cycles: 0,
            accepted: 0,
            from_variant: 0,
            message: [0; 320],
        }
    }
}

/// The recorder's progress, published every 100 ms.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::RecorderStatus")]
pub struct RecorderStatus {
    pub seq: u64,
    pub stage_time_ns: u64,
    /// Messages written to MCAP since the recorder started.
    pub messages: u64,
    /// Samples lost because the recorder fell behind: its buffer for a
    /// service was full, and the publisher (never blocked) overwrote them.
    pub dropped: u64,
    /// Sequence numbers a publisher skipped itself (a stage that took the
    /// newest reading and skipped one, a restarted process): not losses.
    pub gaps: u64,
    /// Bytes written to files, compressed.
    pub bytes: u64,
    /// Files started (more than one when splitting).
    pub files: u32,
    /// Channels being recorded.
    pub channels: u32,
    /// Samples received and not in any file: the disk was full (or would
    /// not take them), counted from the last chunk that reached the file.
    pub unrecorded: u64,
    /// The first of them, by its own timestamp; 0 when there is none.
    pub unrecorded_since_ns: u64,
    /// Times the disk was full.
    pub disk_full: u32,
    /// Oldest parts deleted to keep the recording within `keep_mb`.
    pub deleted_files: u32,
}

/// The shadow model's fit over its last window (`[shadow]`): each output's
/// fit, each part's residual, the drift test's state. Off the loop: its
/// reading is the window's last.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::ShadowSample")]
pub struct ShadowSample {
    /// Windows compared since the shadow started.
    pub seq: u64,
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    pub window_s: f64,
    /// 100 (1 − NRMSE) over the window, percent; NaN where not measured.
    pub fit_theta: f64,
    pub fit_p_a: f64,
    pub fit_p_b: f64,
    /// The residual RMS over the window: the hydraulic part's pressures
    /// (Pa) and the angle (rad, the mechanical or whole part's).
    pub residual_pressures: f64,
    pub residual_angle: f64,
    /// The new segments' log residual, standardized by the model's
    /// validation spread (0: as validated).
    pub normalized_pressures: f64,
    pub normalized_angle: f64,
    /// The drift test's sums and the threshold they alarm at.
    pub cusum_pressures: f64,
    pub cusum_angle: f64,
    pub cusum_threshold: f64,
    /// Residual NRMSE by regime, in `greybox::REGIMES`' order (NaN: no
    /// sample in that regime).
    pub regime_pressures: [f64; 8],
    pub regime_angle: [f64; 8],
    /// Times the rows started afresh after a reading lost, a handover or a
    /// flagged reading: each one delays the next window and a diagnosis.
    pub row_gaps: u64,
    /// Drift alarms so far.
    pub drift_alarms: u32,
    /// 1 while the diagnosis of a drift runs.
    pub diagnosing: u32,
}

/// A drift of the machine away from its model: published when the test
/// alarms (`stage` [`drift::DETECTED`]), and again when the diagnosis has
/// named the effect that changed, or could not.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::ModelDrift")]
pub struct ModelDrift {
    /// Drift messages since the shadow started.
    pub seq: u64,
    /// The reading at which the drift was detected.
    pub sensor_seq: u64,
    pub sensor_time_ns: u64,
    pub stage_time_ns: u64,
    /// The machine's time at detection, s from the shadow's first reading.
    pub detected_after_s: f64,
    /// How far the residual rose, in validation spreads, and as a ratio.
    pub size: f64,
    pub rms_ratio: f64,
    /// The named effect's parameters in the catalog's order (NaN beyond).
    pub params: [f64; 4],
    /// [`drift`] `DETECTED`, `NAMED`, `UNNAMED`.
    pub stage: u32,
    pub reserved: u32,
    /// NUL-padded ASCII: the part, the regime, the effect (once named).
    pub part: [u8; 16],
    pub regime: [u8; 24],
    pub effect: [u8; 24],
}

/// The stages of a [`ModelDrift`].
pub mod drift {
    pub const DETECTED: u32 = 0;
    pub const NAMED: u32 = 1;
    pub const UNNAMED: u32 = 2;
}

/// The latency benchmark's sample: one pass through the five stages, with
/// the time each hop handed it on.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[repr(C)]
#[type_name("hydractl::BenchSample")]
pub struct BenchSample {
    pub seq: u64,
    /// [0]: sent by the driver; [1..=5]: handed on by stage 1..=5.
    pub stamps_ns: [u64; 6],
    pub angle: f64,
    pub p_a: f64,
    pub p_b: f64,
    pub velocity: f64,
    pub torque: f64,
    pub friction: f64,
    pub reference_velocity: f64,
    pub output: f64,
    pub command: f64,
}

impl BenchSample {
    pub const WIRE_SIZE: usize = 8 * 16;

    /// Little-endian bytes, for transports that are not shared memory.
    pub fn to_bytes(&self) -> [u8; Self::WIRE_SIZE] {
        let mut out = [0u8; Self::WIRE_SIZE];
        let words = [self.seq].into_iter().chain(self.stamps_ns).chain(
            [
                self.angle,
                self.p_a,
                self.p_b,
                self.velocity,
                self.torque,
                self.friction,
                self.reference_velocity,
                self.output,
                self.command,
            ]
            .map(f64::to_bits),
        );
        for (chunk, word) in out.chunks_exact_mut(8).zip(words) {
            chunk.copy_from_slice(&word.to_le_bytes());
        }
        out
    }

    pub fn from_bytes(bytes: &[u8; Self::WIRE_SIZE]) -> Self {
        let mut words = [0u64; 16];
        for (word, chunk) in words.iter_mut().zip(bytes.chunks_exact(8)) {
            let mut b = [0u8; 8];
            b.copy_from_slice(chunk);
            *word = u64::from_le_bytes(b);
        }
        let f = |i: usize| f64::from_bits(words[i]);
        Self {
            seq: words[0],
            stamps_ns: [words[1], words[2], words[3], words[4], words[5], words[6]],
            angle: f(7),
            p_a: f(8),
            p_b: f(9),
            velocity: f(10),
            torque: f(11),
            friction: f(12),
            reference_velocity: f(13),
            output: f(14),
            command: f(15),
        }
    }
}

/// Writes `text` into a fixed NUL-padded field, truncating at a character
/// boundary.
pub fn fixed_name<const N: usize>(text: &str) -> [u8; N] {
    let mut end = text.len().min(N);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let mut out = [0u8; N];
    out[..end].copy_from_slice(&text.as_bytes()[..end]);
    out
}

/// Reads a NUL-padded field.
pub fn name_str(bytes: &[u8]) -> &str {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    std::str::from_utf8(&bytes[..end]).unwrap_or("?")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::size_of;

    #[test]
    fn no_hidden_padding() {
        assert_eq!(size_of::<PlantReading>(), 7 * 8 + 8);
        assert_eq!(size_of::<SensorSample>(), 8 * 8 + 8);
        assert_eq!(size_of::<FrictionSample>(), 6 * 8);
        assert_eq!(size_of::<PositionSample>(), 8 * 8 + 8);
        assert_eq!(size_of::<TorqueSample>(), 6 * 8 + 8);
        assert_eq!(size_of::<ValveSample>(), 5 * 8 + 8);
        assert_eq!(size_of::<ProcessStatus>(), 16 + 16 + 20);
        assert_eq!(size_of::<SupervisorStatus>(), 16 + MAX_PROCESSES * 52 + 8);
        assert_eq!(size_of::<RecorderStatus>(), 10 * 8);
        assert_eq!(size_of::<Handover>(), 5 * 8);
        assert_eq!(size_of::<SupervisorEvent>(), 12 * 8 + 8 + 48);
        assert_eq!(size_of::<SupervisorReply>(), 16 + 8 + 320);
        assert_eq!(size_of::<ValveDevice>(), 4 * 8 + 4 * 4 + 16 + 128);
    }

    #[test]
    fn bench_sample_round_trips_through_bytes() {
        let s = BenchSample {
            seq: 7,
            stamps_ns: [1, 2, 3, 4, 5, 6],
            angle: 0.5,
            command: -0.25,
            ..BenchSample::default()
        };
        assert_eq!(BenchSample::from_bytes(&s.to_bytes()), s);
        assert_eq!(size_of::<BenchSample>(), BenchSample::WIRE_SIZE);
    }

    #[test]
    fn fixed_names_round_trip() {
        let n: [u8; 16] = fixed_name("position");
        assert_eq!(name_str(&n), "position");
        let long: [u8; 4] = fixed_name("supervisor");
        assert_eq!(name_str(&long), "supe");
        let accented: [u8; 4] = fixed_name("ab\u{b5}s");
        assert_eq!(name_str(&accented), "ab\u{b5}");
        let cut: [u8; 3] = fixed_name("ab\u{b5}s");
        assert_eq!(name_str(&cut), "ab");
    }
}
