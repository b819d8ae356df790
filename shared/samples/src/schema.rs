//! What a recorder needs to know of each sample type: its iceoryx2 type
//! name, and a `ros2msg` schema describing its `#[repr(C)]` fields, so that
//! Foxglove and PlotJuggler decode a recorded sample by reflection, with no
//! plugin. A sample is recorded as [`CDR_HEADER`] followed by its own bytes:
//! fields ordered largest first sit exactly where little-endian CDR puts
//! them, so the sample's memory *is* its CDR encoding.
//!
//! Every sample's first field is a `u64` sequence number, so a recording's
//! gaps are read from any channel the same way.

use std::fmt::Debug;
use std::mem::size_of;

use iceoryx2::prelude::ZeroCopySend;

use crate::{
    BenchSample, FrictionSample, Handover, HandoverAck, ModelDrift, PlantReading, PositionSample, RecorderStatus,
    SensorSample, ShadowSample, SupervisorEvent, SupervisorStatus, TorqueSample, ValveDevice, ValveSample,
};

#[cfg(not(target_endian = "little"))]
compile_error!("samples are recorded as little-endian CDR: their memory must be little-endian");

/// CDR encapsulation header: plain CDR, little-endian, no options.
pub const CDR_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// One sample type, described for recording.
#[derive(Debug, PartialEq, Eq)]
pub struct SampleKind {
    /// The type name iceoryx2 keeps in the service's static config.
    pub type_name: &'static str,
    /// The ROS 2 style name of the schema, `package/msg/Type`.
    pub schema_name: &'static str,
    /// The `ros2msg` definition, with its nested messages after separators.
    pub ros2msg: &'static str,
    /// `size_of` the type: the bytes after the CDR header.
    pub size: usize,
    /// Where the sample's own timestamp (CLOCK_MONOTONIC ns) sits: its
    /// stage's time, or the reading's for the plant.
    pub time_offset: usize,
    /// Fields that are NUL-padded text in memory and `string`s in the
    /// schema, with their size in memory: where the sample's memory is not
    /// its CDR ([`crate::cdr`]). Empty for most samples.
    pub text: &'static [(&'static str, usize)],
}

impl SampleKind {
    /// The sequence number, the first field of every sample.
    pub fn sequence(&self, bytes: &[u8]) -> Option<u64> {
        self.u64_at(bytes, 0)
    }

    /// The sample's own timestamp, ns.
    pub fn timestamp_ns(&self, bytes: &[u8]) -> Option<u64> {
        self.u64_at(bytes, self.time_offset)
    }

    fn u64_at(&self, bytes: &[u8], offset: usize) -> Option<u64> {
        if bytes.len() != self.size {
            return None;
        }
        let field: [u8; 8] = bytes.get(offset..offset + 8)?.try_into().ok()?;
        Some(u64::from_le_bytes(field))
    }
}

/// A sample type that can be recorded and replayed.
pub trait Recordable: ZeroCopySend + bytemuck::Pod + Debug + 'static {
    const KIND: SampleKind;
}

/// Calls back with the type whose [`SampleKind::type_name`] is given: the one
/// place where a type name read at run time becomes a Rust type.
pub trait KindVisitor {
    type Output;
    fn visit<T: Recordable>(self) -> Self::Output;
}

/// Every recordable kind.
pub const KINDS: [&SampleKind; 15] = [
    &PlantReading::KIND,
    &SensorSample::KIND,
    &FrictionSample::KIND,
    &PositionSample::KIND,
    &TorqueSample::KIND,
    &ValveSample::KIND,
    &SupervisorStatus::KIND,
    &RecorderStatus::KIND,
    &Handover::KIND,
    &HandoverAck::KIND,
    &SupervisorEvent::KIND,
    &BenchSample::KIND,
    &ShadowSample::KIND,
    &ModelDrift::KIND,
    &ValveDevice::KIND,
];

/// The stack's own services and what they carry: the recorder subscribes
/// to these before their publishers exist, discovery finds the rest.
pub const STACK_SERVICES: [(&str, &SampleKind); 14] = [
    (crate::service::PLANT_READING, &PlantReading::KIND),
    (crate::service::SENSOR, &SensorSample::KIND),
    (crate::service::FRICTION, &FrictionSample::KIND),
    (crate::service::POSITION, &PositionSample::KIND),
    (crate::service::TORQUE, &TorqueSample::KIND),
    (crate::service::VALVE, &ValveSample::KIND),
    (crate::service::SUPERVISOR_STATUS, &SupervisorStatus::KIND),
    (crate::service::RECORDER_STATUS, &RecorderStatus::KIND),
    (crate::service::SUPERVISOR_EVENTS, &SupervisorEvent::KIND),
    (crate::service::HANDOVER, &Handover::KIND),
    (crate::service::HANDOVER_ACK, &HandoverAck::KIND),
    (crate::service::SHADOW, &ShadowSample::KIND),
    (crate::service::SHADOW_DRIFT, &ModelDrift::KIND),
    (crate::service::VALVE_DEVICE, &ValveDevice::KIND),
];

/// Visits the type named `type_name`; `None` for a type we do not know.
pub fn visit_kind<V: KindVisitor>(type_name: &str, visitor: V) -> Option<V::Output> {
    fn is<T: Recordable>(name: &str) -> bool {
        T::KIND.type_name == name
    }
    Some(match type_name {
        n if is::<PlantReading>(n) => visitor.visit::<PlantReading>(),
        n if is::<SensorSample>(n) => visitor.visit::<SensorSample>(),
        n if is::<FrictionSample>(n) => visitor.visit::<FrictionSample>(),
        n if is::<PositionSample>(n) => visitor.visit::<PositionSample>(),
        n if is::<TorqueSample>(n) => visitor.visit::<TorqueSample>(),
        n if is::<ValveSample>(n) => visitor.visit::<ValveSample>(),
        n if is::<SupervisorStatus>(n) => visitor.visit::<SupervisorStatus>(),
        n if is::<RecorderStatus>(n) => visitor.visit::<RecorderStatus>(),
        n if is::<Handover>(n) => visitor.visit::<Handover>(),
        n if is::<HandoverAck>(n) => visitor.visit::<HandoverAck>(),
        n if is::<SupervisorEvent>(n) => visitor.visit::<SupervisorEvent>(),
        n if is::<BenchSample>(n) => visitor.visit::<BenchSample>(),
        n if is::<ShadowSample>(n) => visitor.visit::<ShadowSample>(),
        n if is::<ModelDrift>(n) => visitor.visit::<ModelDrift>(),
        n if is::<ValveDevice>(n) => visitor.visit::<ValveDevice>(),
        _ => return None,
    })
}

macro_rules! recordable {
    ($type:ty, $name:literal, $time:ident, $msg:expr) => {
        recordable!($type, $name, $time, $msg, &[]);
    };
    ($type:ty, $name:literal, $time:ident, $msg:expr, $text:expr) => {
        impl Recordable for $type {
            const KIND: SampleKind = SampleKind {
                type_name: concat!("hydractl::", $name),
                schema_name: concat!("hydractl/msg/", $name),
                ros2msg: $msg,
                size: size_of::<$type>(),
                time_offset: std::mem::offset_of!($type, $time),
                text: $text,
            };
        }
    };
}

recordable!(
    PlantReading,
    "PlantReading",
    sensor_time_ns,
    "uint64 sensor_seq\nuint64 sensor_time_ns\nfloat64 angle\nfloat64 p_a\nfloat64 p_b\nfloat64 true_angle\nuint64 late_commands\nuint32 source\nuint32 amplifier_neutral_for\n"
);
recordable!(
    SensorSample,
    "SensorSample",
    stage_time_ns,
    "uint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 angle\nfloat64 velocity\nfloat64 p_a\nfloat64 p_b\nfloat64 torque\nuint32 valid\nuint32 source\n"
);
recordable!(
    FrictionSample,
    "FrictionSample",
    stage_time_ns,
    "uint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 compensation\nfloat64 blended_velocity\nfloat64 load_feedforward\n"
);
recordable!(
    PositionSample,
    "PositionSample",
    stage_time_ns,
    "uint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 reference_angle\nfloat64 reference_velocity\nfloat64 reference_acceleration\nfloat64 angle\nfloat64 output\nuint32 structure\nuint32 variant\n"
);
recordable!(
    TorqueSample,
    "TorqueSample",
    stage_time_ns,
    "uint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 torque_reference\nfloat64 torque\nfloat64 command\nuint32 variant\nuint32 reserved\n"
);
recordable!(
    ValveSample,
    "ValveSample",
    stage_time_ns,
    "uint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 command\nfloat64 requested\nuint32 faults\nuint32 variant\n"
);
recordable!(
    SupervisorStatus,
    "SupervisorStatus",
    stage_time_ns,
    "uint64 seq\nuint64 stage_time_ns\nProcessStatus[12] processes\nuint32 process_count\nuint32 plant_is_simulation\n\
================================================================================\n\
MSG: hydractl/ProcessStatus\n\
string name\nstring variant\nuint32 pid\nuint32 restarts\nuint32 healthy\nuint32 page_faults_after_start\nuint32 memory_locked\n",
    &[("name", 16), ("variant", 16)]
);
recordable!(
    RecorderStatus,
    "RecorderStatus",
    stage_time_ns,
    "uint64 seq\nuint64 stage_time_ns\nuint64 messages\nuint64 dropped\nuint64 gaps\nuint64 bytes\nuint32 files\nuint32 channels\nuint64 unrecorded\nuint64 unrecorded_since_ns\nuint32 disk_full\nuint32 deleted_files\n"
);
recordable!(
    Handover,
    "Handover",
    stage_time_ns,
    "uint64 seq\nuint64 stage_time_ns\nuint64 at_seq\nuint32 new_pid\nuint32 stage\nuint32 variant\nuint32 reserved\n"
);
recordable!(
    HandoverAck,
    "HandoverAck",
    stage_time_ns,
    "uint64 handover_seq\nuint64 stage_time_ns\nuint64 at_seq\nuint32 pid\nuint32 taking\n"
);
recordable!(
    SupervisorEvent,
    "SupervisorEvent",
    stage_time_ns,
    "uint64 seq\nuint64 stage_time_ns\nuint64 sensor_seq\nuint64 missed_cycles\nfloat64 command_step\nfloat64 loop_step_before\nfloat64 loop_step_after\nfloat64 tracking_rms_before_rad\nfloat64 tracking_rms_after_rad\nuint64 valve_safe_after_periods\nuint64 detected_after_ns\nuint64 restarted_after_ns\nuint32 kind\nuint32 pid\nstring process\nstring from\nstring to\n",
    &[("process", 16), ("from", 16), ("to", 16)]
);
recordable!(
    ValveDevice,
    "ValveDevice",
    stage_time_ns,
    "uint64 seq\nuint64 stage_time_ns\nuint64 latched_since_unix_ns\nuint64 reset_time_ns\nuint32 fault_code\nuint32 latched\nuint32 resets\nuint32 reserved\nstring state\nstring meaning\n",
    &[("state", 16), ("meaning", 128)]
);
recordable!(
    BenchSample,
    "BenchSample",
    stamps_ns,
    "uint64 seq\nuint64[6] stamps_ns\nfloat64 angle\nfloat64 p_a\nfloat64 p_b\nfloat64 velocity\nfloat64 torque\nfloat64 friction\nfloat64 reference_velocity\nfloat64 output\nfloat64 command\n"
);
recordable!(
    ShadowSample,
    "ShadowSample",
    stage_time_ns,
    "uint64 seq\nuint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 window_s\nfloat64 fit_theta\nfloat64 fit_p_a\nfloat64 fit_p_b\nfloat64 residual_pressures\nfloat64 residual_angle\nfloat64 normalized_pressures\nfloat64 normalized_angle\nfloat64 cusum_pressures\nfloat64 cusum_angle\nfloat64 cusum_threshold\nfloat64[8] regime_pressures\nfloat64[8] regime_angle\nuint64 row_gaps\nuint32 drift_alarms\nuint32 diagnosing\n"
);
recordable!(
    ModelDrift,
    "ModelDrift",
    stage_time_ns,
    "uint64 seq\nuint64 sensor_seq\nuint64 sensor_time_ns\nuint64 stage_time_ns\nfloat64 detected_after_s\nfloat64 size\nfloat64 rms_ratio\nfloat64[4] params\nuint32 stage\nuint32 reserved\nstring part\nstring regime\nstring effect\n",
    &[("part", 16), ("regime", 24), ("effect", 24)]
);

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;

    /// The little-endian CDR layout of a ros2msg definition: the size of
    /// each primitive, aligned to itself; nested messages inline.
    fn cdr_size(kind: &SampleKind) -> (usize, Vec<(String, usize)>) {
        let msg = kind.ros2msg;
        let mut sections =
            msg.split("================================================================================\n");
        let main = sections.next().unwrap_or_default();
        let mut nested = HashMap::new();
        for section in sections {
            let (header, body) = section.split_once('\n').expect("a nested message has a header");
            let name = header.strip_prefix("MSG: hydractl/").expect("MSG: header");
            nested.insert(name.to_owned(), body.to_owned());
        }
        let mut fields = Vec::new();
        let offset = layout(main, &nested, kind.text, 0, &mut fields);
        (offset, fields)
    }

    fn layout(
        body: &str,
        nested: &HashMap<String, String>,
        text: &[(&str, usize)],
        mut offset: usize,
        fields: &mut Vec<(String, usize)>,
    ) -> usize {
        for line in body.lines().filter(|l| !l.trim().is_empty()) {
            let (ty, name) = line.split_once(' ').expect("type and name");
            let (base, count) = match ty.split_once('[') {
                Some((b, n)) => (b, n.trim_end_matches(']').parse::<usize>().expect("a fixed array")),
                None => (ty, 1),
            };
            let primitive = match base {
                "uint8" => Some(1),
                "uint32" => Some(4),
                "uint64" | "float64" => Some(8),
                _ => None,
            };
            // Text: bytes in memory, a string in CDR.
            let text_len = (base == "string").then(|| {
                text.iter()
                    .find(|(n, _)| *n == name)
                    .map(|(_, len)| *len)
                    .expect("a string has its size in memory")
            });
            if let Some(len) = text_len {
                fields.push((name.to_owned(), offset));
                offset += len * count;
                continue;
            }
            match primitive {
                Some(size) => {
                    offset = offset.div_ceil(size) * size;
                    fields.push((name.to_owned(), offset));
                    offset += size * count;
                }
                None => {
                    let inner = nested.get(base).expect("nested message defined");
                    fields.push((name.to_owned(), offset));
                    for _ in 0..count {
                        offset = layout(inner, nested, text, offset, &mut Vec::new());
                    }
                }
            }
        }
        offset
    }

    #[test]
    fn every_schema_matches_its_type_layout_and_starts_with_a_sequence() {
        for kind in KINDS {
            let (size, fields) = cdr_size(kind);
            assert_eq!(size, kind.size, "{}: CDR size against size_of", kind.schema_name);
            let (first, offset) = &fields[0];
            assert!(first.ends_with("seq") && *offset == 0, "{}", kind.schema_name);
            assert!(kind.ros2msg.starts_with("uint64 "), "{}", kind.schema_name);
        }
    }

    #[test]
    fn schema_offsets_are_the_struct_offsets() {
        let (_, fields) = cdr_size(&SensorSample::KIND);
        let at = |name: &str| fields.iter().find(|(n, _)| n == name).map(|(_, o)| *o);
        assert_eq!(at("torque"), Some(std::mem::offset_of!(SensorSample, torque)));
        assert_eq!(at("valid"), Some(std::mem::offset_of!(SensorSample, valid)));
        let (_, fields) = cdr_size(&SupervisorStatus::KIND);
        let at = |name: &str| fields.iter().find(|(n, _)| n == name).map(|(_, o)| *o);
        assert_eq!(
            at("process_count"),
            Some(std::mem::offset_of!(SupervisorStatus, process_count))
        );
    }

    struct NameOf;
    impl KindVisitor for NameOf {
        type Output = &'static str;
        fn visit<T: Recordable>(self) -> &'static str {
            T::KIND.schema_name
        }
    }

    #[test]
    fn sequence_and_timestamp_are_read_from_the_bytes() {
        let v = ValveSample {
            sensor_seq: 41,
            stage_time_ns: 1234,
            ..ValveSample::default()
        };
        let bytes = bytemuck::bytes_of(&v);
        assert_eq!(ValveSample::KIND.sequence(bytes), Some(41));
        assert_eq!(ValveSample::KIND.timestamp_ns(bytes), Some(1234));
        assert_eq!(ValveSample::KIND.sequence(&bytes[..8]), None);
    }

    #[test]
    fn type_names_visit_their_types() {
        for kind in KINDS {
            assert_eq!(visit_kind(kind.type_name, NameOf), Some(kind.schema_name));
        }
        assert_eq!(visit_kind("hydractl::Unknown", NameOf), None);
    }

    #[test]
    #[allow(unsafe_code)]
    fn type_names_are_the_ones_iceoryx2_keeps() {
        use iceoryx2_bb_elementary_traits::type_name::TypeName;
        // SAFETY: type_name only returns the derive's string.
        let ice = unsafe { <SensorSample as TypeName>::type_name() };
        assert_eq!(ice, SensorSample::KIND.type_name);
        let ice = unsafe { <SupervisorStatus as TypeName>::type_name() };
        assert_eq!(ice, SupervisorStatus::KIND.type_name);
    }
}
