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

use bytemuck::{Pod, Zeroable};
use iceoryx2::prelude::*;

mod schema;
pub use schema::{visit_kind, KindVisitor, Recordable, SampleKind, CDR_HEADER, KINDS, STACK_SERVICES};

/// Service names. Each publish-subscribe service has an event service of
/// the same name, notified after every sample.
pub mod service {
    /// The plant's raw readings: the simulated sensor bus.
    pub const PLANT_READING: &str = "hydractl/plant/reading";
    pub const SENSOR: &str = "hydractl/sensor";
    pub const FRICTION: &str = "hydractl/friction";
    pub const POSITION: &str = "hydractl/position";
    pub const TORQUE: &str = "hydractl/torque";
    /// The valve's state: the command it drives, and its faults.
    pub const VALVE: &str = "hydractl/valve";
    /// The supervisor's view of every process.
    pub const SUPERVISOR_STATUS: &str = "hydractl/supervisor/status";
    /// The recorder's progress: messages written, samples missed, files.
    pub const RECORDER_STATUS: &str = "hydractl/recorder/status";
}

/// Validity flags of a sensor sample.
pub mod valid {
    pub const ANGLE: u32 = 1 << 0;
    pub const PRESSURE_A: u32 = 1 << 1;
    pub const PRESSURE_B: u32 = 1 << 2;
    pub const ALL: u32 = ANGLE | PRESSURE_A | PRESSURE_B;
}

/// Fault flags of the valve's state.
pub mod fault {
    /// No fresh command: older than the configured number of periods.
    pub const STALE: u32 = 1 << 0;
    /// The command was NaN or infinite.
    pub const NOT_FINITE: u32 = 1 << 1;
    /// The command was outside [-1, 1].
    pub const OUT_OF_RANGE: u32 = 1 << 2;
    /// The sensor sample the command derives from was not valid.
    pub const INVALID_SENSOR: u32 = 1 << 3;
}

/// Codes of the structure and variants, for samples that report them.
pub mod code {
    pub const STRUCTURE_POSITION: u32 = 0;
    pub const STRUCTURE_CASCADE: u32 = 1;
    pub const VARIANT_PID: u32 = 0;
    pub const VARIANT_MFC: u32 = 1;
    pub const VARIANT_HINF: u32 = 2;
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
    pub reserved: u32,
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
    pub reserved: u32,
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
    pub reserved: u32,
}

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

/// Writes `text` into a fixed NUL-padded field, truncating.
pub fn fixed_name<const N: usize>(text: &str) -> [u8; N] {
    let mut out = [0u8; N];
    for (o, b) in out.iter_mut().zip(text.bytes()) {
        *o = b;
    }
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
        assert_eq!(size_of::<PlantReading>(), 7 * 8);
        assert_eq!(size_of::<SensorSample>(), 8 * 8 + 8);
        assert_eq!(size_of::<FrictionSample>(), 5 * 8);
        assert_eq!(size_of::<PositionSample>(), 8 * 8 + 8);
        assert_eq!(size_of::<TorqueSample>(), 6 * 8 + 8);
        assert_eq!(size_of::<ValveSample>(), 5 * 8 + 8);
        assert_eq!(size_of::<ProcessStatus>(), 16 + 16 + 16);
        assert_eq!(size_of::<SupervisorStatus>(), 16 + MAX_PROCESSES * 48 + 8);
        assert_eq!(size_of::<RecorderStatus>(), 7 * 8);
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
    }
}
