//! The `[can]` table: which nodes the machine's devices are, which
//! COB-IDs and mappings their PDOs use, how their values scale, the
//! bitrate and the timeouts. Defaults are the profiles' own (the
//! predefined connection set, the valve's PDOs as the PVED-CC's EDS maps
//! them); [`CanConfig::resolve`] checks the whole before anything opens a
//! bus: node IDs, clashing COB-IDs, mappings that lack their object.

use serde::{Deserialize, Serialize};

use crate::canopen::{cob_id, MapEntry, NodeId, PdoMapping};
use crate::encoder::EncoderScale;
use crate::pressure::{PressureScale, PressureUnit, ValueType};
use crate::valve::object as valve_object;
use crate::{CanError, Frame};

pub use crate::budget::{Budget, BudgetLine};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// The virtual bus over shared memory, on this machine.
    Virtual,
    /// A SocketCAN interface.
    Socketcan,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CanConfig {
    pub transport: Transport,
    /// The interface's name (`can0`); on the virtual bus, its name in logs.
    pub interface: String,
    /// bit/s.
    pub bitrate: u32,
    /// The share of a period the period's frames may take at most, their
    /// worst-case stuffing counted: the rest is room for arbitration,
    /// heartbeats and SDO traffic.
    pub max_bus_load: f64,
    pub sync_cob_id: u16,
    /// Heartbeat producer time every node is given (0x1017), ms.
    pub heartbeat_ms: u16,
    /// A node whose heartbeat has not come for this long is lost (0x1016), ms.
    pub heartbeat_timeout_ms: u16,
    /// A period's PDO that has not come this long after its SYNC is late:
    /// the reading is marked invalid rather than waited for, µs.
    pub pdo_deadline_us: u32,
    pub valve: ValveNode,
    pub encoder: EncoderNode,
    pub pressure_a: PressureNode,
    pub pressure_b: PressureNode,
    /// Faults the virtual bus's wire injects, for trying the stack's
    /// reactions; absent on a real bus.
    pub faults: Option<WireFaults>,
}

/// What the virtual bus's wire does wrong, from `after_s` (after the wire
/// starts) until `until_s`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WireFaults {
    pub after_s: f64,
    #[serde(default)]
    pub until_s: Option<f64>,
    /// Frames with this COB-ID wait `delay_us` before they contend.
    #[serde(default)]
    pub delay_cob_id: Option<u16>,
    #[serde(default)]
    pub delay_us: u32,
    /// Transmissions destroyed by an error frame (and sent again) at `after_s`.
    #[serde(default)]
    pub error_frames: u32,
    /// The bus goes off from `after_s` (nothing crosses) until `until_s`.
    #[serde(default)]
    pub bus_off: bool,
}

impl Default for CanConfig {
    fn default() -> Self {
        Self {
            transport: Transport::Virtual,
            interface: "vcan0".to_string(),
            bitrate: 1_000_000,
            max_bus_load: 0.8,
            sync_cob_id: cob_id::SYNC,
            heartbeat_ms: 100,
            heartbeat_timeout_ms: 300,
            pdo_deadline_us: 800,
            valve: ValveNode::default(),
            encoder: EncoderNode::default(),
            pressure_a: PressureNode::with_node(0x30),
            pressure_b: PressureNode::with_node(0x31),
            faults: None,
        }
    }
}

/// A PDO: its COB-ID (the predefined connection set's when absent) and
/// its mapping as the 32-bit entries of objects 0x16xx / 0x1Axx.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PdoConfig {
    pub number: u8,
    #[serde(default)]
    pub cob_id: Option<u16>,
    pub mapping: Vec<u32>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValveNode {
    pub node: NodeId,
    /// The valve's own guard: with no set point for this long it faults to
    /// hold (spool neutral) and sends an EMCY, ms.
    pub rpdo_timeout_ms: u16,
    /// The spool's reported position (0x6301:1) may be this far from its
    /// set point (a share of its travel) for `spool_hold_ms` before it is
    /// a fault (stuck, or a wrong sign): room for the spool's own lag and
    /// ringing after a step.
    pub spool_tolerance: f64,
    pub spool_hold_ms: u32,
    /// Receives the set point (0x6300:1).
    pub set_point: PdoConfig,
    /// Receives the control word (0x6040) and device mode (0x6042).
    pub control: PdoConfig,
    /// Sends the status word (0x6041) and spool position (0x6301:1).
    pub status: PdoConfig,
}

impl Default for ValveNode {
    fn default() -> Self {
        Self {
            node: 0x10,
            rpdo_timeout_ms: 20,
            spool_tolerance: 0.3,
            spool_hold_ms: 500,
            set_point: PdoConfig {
                number: 1,
                cob_id: None,
                // A 16-bit dummy, then the set point: the PVED-CC's RPDO1.
                mapping: vec![0x0003_0010, 0x6300_0110],
            },
            control: PdoConfig {
                number: 2,
                cob_id: None,
                mapping: vec![0x6040_0010, 0x6042_0008],
            },
            status: PdoConfig {
                number: 1,
                cob_id: None,
                mapping: vec![0x6041_0010, 0x6301_0110],
            },
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EncoderNode {
    pub node: NodeId,
    /// Measuring steps per turn (object 0x6001).
    pub counts_per_revolution: u32,
    /// The count at angle zero.
    pub zero_count: i32,
    /// Sends the position value (0x6004) on every SYNC.
    pub position: PdoConfig,
}

impl Default for EncoderNode {
    fn default() -> Self {
        Self {
            node: 0x20,
            counts_per_revolution: EncoderScale::default().counts_per_revolution,
            zero_count: 0,
            position: PdoConfig {
                number: 1,
                cob_id: None,
                mapping: vec![0x6004_0020],
            },
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PressureNode {
    pub node: NodeId,
    /// The transducer's channel: the process value's sub-index.
    pub channel: u8,
    pub value_type: ValueType,
    /// Object 0x6132: the integer value is in units of 10^-digits.
    pub decimal_digits: u8,
    pub unit: PressureUnit,
    /// Sends the process value on every SYNC; when its mapping is absent,
    /// the channel's process value of `value_type` alone.
    pub value: Option<PdoConfig>,
}

impl Default for PressureNode {
    fn default() -> Self {
        Self::with_node(0x30)
    }
}

impl EncoderNode {
    pub fn scale(&self) -> EncoderScale {
        EncoderScale {
            counts_per_revolution: self.counts_per_revolution,
            zero_count: self.zero_count,
        }
    }
}

impl PressureNode {
    pub fn scale(&self) -> PressureScale {
        PressureScale {
            value_type: self.value_type,
            decimal_digits: self.decimal_digits,
            unit: self.unit,
        }
    }

    fn with_node(node: NodeId) -> Self {
        Self {
            node,
            channel: 1,
            value_type: PressureScale::default().value_type,
            decimal_digits: PressureScale::default().decimal_digits,
            unit: PressureScale::default().unit,
            value: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[can{section}] {reason}")]
pub struct ProfileError {
    /// `.valve`, `.encoder`, … or empty for the table itself.
    pub section: String,
    pub reason: String,
}

fn error(section: &str, reason: impl Into<String>) -> ProfileError {
    ProfileError {
        section: section.to_string(),
        reason: reason.into(),
    }
}

/// A PDO resolved: where it goes and what it carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pdo {
    pub cob_id: u16,
    pub mapping: PdoMapping,
    /// Byte offset and width of the object this stack reads or writes.
    pub value_at: (usize, u8),
}

impl Pdo {
    /// The index among the mapping's entries of the object at byte `at.0`.
    pub fn slot(&self, at: (usize, u8)) -> usize {
        let mut offset = 0;
        for (i, e) in self.mapping.entries().iter().enumerate() {
            if offset == at.0 {
                return i;
            }
            offset += usize::from(e.bits / 8);
        }
        0
    }

    /// The raw value of the object this stack reads (`value_at`); a frame
    /// of the wrong length is refused, naming its COB-ID and `what`.
    pub fn read(&self, frame: &Frame, what: &'static str) -> Result<u64, CanError> {
        Ok(self.mapping.unpack(frame, what)?[self.slot(self.value_at)])
    }
}

/// The `[can]` table checked and resolved: every COB-ID and mapping the
/// processes use, plain data for their loops.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    pub interface: String,
    pub transport: Transport,
    pub bitrate: u32,
    pub max_bus_load: f64,
    pub sync_cob_id: u16,
    pub heartbeat_ms: u16,
    pub heartbeat_timeout_ms: u16,
    pub pdo_deadline_us: u32,
    pub valve: NodeId,
    pub valve_rpdo_timeout_ms: u16,
    /// The set point's RPDO number: its timer is the valve's own guard.
    pub valve_set_point_rpdo: u8,
    pub valve_spool_tolerance: f64,
    pub valve_spool_hold_ms: u32,
    pub valve_set_point: Pdo,
    /// `value_at` is the control word's; the device mode follows it.
    pub valve_control: Pdo,
    /// `value_at` is the spool position's; the status word's is
    /// `valve_status_word_at`.
    pub valve_status: Pdo,
    pub valve_status_word_at: (usize, u8),
    pub encoder: NodeId,
    pub encoder_scale: EncoderScale,
    pub encoder_position: Pdo,
    pub pressure: [PressureChannel; 2],
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressureChannel {
    pub node: NodeId,
    pub scale: PressureScale,
    pub value: Pdo,
}

impl CanConfig {
    pub fn resolve(&self) -> Result<Profile, ProfileError> {
        if !(10_000..=1_000_000).contains(&self.bitrate) {
            return Err(error(
                "",
                format!("bitrate = {}: classic CAN runs at 10 kbit/s to 1 Mbit/s", self.bitrate),
            ));
        }
        if let Some(f) = &self.faults {
            let until_ok = f.until_s.is_none_or(|u| u.is_finite() && u > f.after_s);
            if !(f.after_s.is_finite() && f.after_s >= 0.0 && until_ok && f.delay_us <= 1_000_000) {
                return Err(error(
                    ".faults",
                    format!(
                        "after_s = {}, until_s = {:?}, delay_us = {}: after_s at least 0, until_s after it, a delay of at most 1 s",
                        f.after_s, f.until_s, f.delay_us
                    ),
                ));
            }
        }
        if !(self.max_bus_load > 0.0 && self.max_bus_load <= 1.0) {
            return Err(error(
                "",
                format!("max_bus_load = {}: a share in (0, 1]", self.max_bus_load),
            ));
        }
        if self.heartbeat_ms == 0 || self.heartbeat_timeout_ms <= self.heartbeat_ms {
            return Err(error(
                "",
                format!(
                    "heartbeat_timeout_ms = {} must exceed heartbeat_ms = {} (both above 0)",
                    self.heartbeat_timeout_ms, self.heartbeat_ms
                ),
            ));
        }
        if self.interface.is_empty() {
            return Err(error("", "interface is empty"));
        }
        if u32::from(self.sync_cob_id) > crate::Frame::MAX_STANDARD_ID {
            return Err(error(
                "",
                format!("sync_cob_id = {:#x} is above 0x7FF", self.sync_cob_id),
            ));
        }
        let nodes = [
            (".valve", self.valve.node),
            (".encoder", self.encoder.node),
            (".pressure_a", self.pressure_a.node),
            (".pressure_b", self.pressure_b.node),
        ];
        for (section, node) in nodes {
            if !(1..=127).contains(&node) {
                return Err(error(section, format!("node = {node}: CANopen node IDs are 1 to 127")));
            }
        }
        for (i, (a, node)) in nodes.iter().enumerate() {
            if let Some((b, _)) = nodes[i + 1..].iter().find(|(_, other)| other == node) {
                return Err(error("", format!("[can{a}] and [can{b}] are both node {node}")));
            }
        }
        let valve = &self.valve;
        let valve_set_point = pdo(
            ".valve.set_point",
            &valve.set_point,
            Direction::Rpdo,
            valve.node,
            (valve_object::SET_POINT, 1),
        )?;
        let valve_control = pdo(
            ".valve.control",
            &valve.control,
            Direction::Rpdo,
            valve.node,
            (valve_object::CONTROL_WORD, 0),
        )?;
        if valve_control.mapping.locate(valve_object::DEVICE_MODE, 0).is_none() {
            return Err(error(".valve.control", "the mapping lacks the device mode 0x6042:0"));
        }
        // The objects' own widths: a set point mapped with 8 bits would be
        // read as another number.
        check_width(".valve.set_point", &valve_set_point, (valve_object::SET_POINT, 1), 16)?;
        check_width(".valve.control", &valve_control, (valve_object::CONTROL_WORD, 0), 16)?;
        check_width(".valve.control", &valve_control, (valve_object::DEVICE_MODE, 0), 8)?;
        let valve_status = pdo(
            ".valve.status",
            &valve.status,
            Direction::Tpdo,
            valve.node,
            (valve_object::ACTUAL_VALUE, 1),
        )?;
        let valve_status_word_at = valve_status
            .mapping
            .locate(valve_object::STATUS_WORD, 0)
            .ok_or_else(|| error(".valve.status", "the mapping lacks the status word 0x6041:0"))?;
        check_width(".valve.status", &valve_status, (valve_object::STATUS_WORD, 0), 16)?;
        check_width(".valve.status", &valve_status, (valve_object::ACTUAL_VALUE, 1), 16)?;
        if valve.rpdo_timeout_ms == 0 {
            return Err(error(".valve", "rpdo_timeout_ms = 0: the valve's own guard must be on"));
        }
        if !(valve.spool_tolerance > 0.0 && valve.spool_tolerance <= 1.0) || valve.spool_hold_ms == 0 {
            return Err(error(
                ".valve",
                format!(
                    "spool_tolerance = {}, spool_hold_ms = {}: a share of the travel in (0, 1] and a time above 0",
                    valve.spool_tolerance, valve.spool_hold_ms
                ),
            ));
        }
        let encoder_position = pdo(
            ".encoder.position",
            &self.encoder.position,
            Direction::Tpdo,
            self.encoder.node,
            (crate::encoder::object::POSITION, 0),
        )?;
        check_width(
            ".encoder.position",
            &encoder_position,
            (crate::encoder::object::POSITION, 0),
            32,
        )?;
        if self.encoder.counts_per_revolution == 0 {
            return Err(error(".encoder", "counts_per_revolution = 0"));
        }
        let pressure = [
            pressure_channel(".pressure_a", &self.pressure_a)?,
            pressure_channel(".pressure_b", &self.pressure_b)?,
        ];
        let profile = Profile {
            interface: self.interface.clone(),
            transport: self.transport,
            bitrate: self.bitrate,
            max_bus_load: self.max_bus_load,
            sync_cob_id: self.sync_cob_id,
            heartbeat_ms: self.heartbeat_ms,
            heartbeat_timeout_ms: self.heartbeat_timeout_ms,
            pdo_deadline_us: self.pdo_deadline_us,
            valve: valve.node,
            valve_rpdo_timeout_ms: valve.rpdo_timeout_ms,
            valve_set_point_rpdo: valve.set_point.number,
            valve_spool_tolerance: valve.spool_tolerance,
            valve_spool_hold_ms: valve.spool_hold_ms,
            valve_set_point,
            valve_control,
            valve_status,
            valve_status_word_at,
            encoder: self.encoder.node,
            encoder_scale: self.encoder.scale(),
            encoder_position,
            pressure,
        };
        profile.check_clashes()?;
        Ok(profile)
    }
}

#[derive(Clone, Copy)]
enum Direction {
    Rpdo,
    Tpdo,
}

fn pdo(
    section: &str,
    config: &PdoConfig,
    direction: Direction,
    node: NodeId,
    value: (u16, u8),
) -> Result<Pdo, ProfileError> {
    if !(1..=4).contains(&config.number) {
        return Err(error(section, format!("number = {}: PDOs 1 to 4", config.number)));
    }
    let cob_id = config.cob_id.unwrap_or(match direction {
        Direction::Rpdo => cob_id::rpdo(config.number, node),
        Direction::Tpdo => cob_id::tpdo(config.number, node),
    });
    if u32::from(cob_id) > crate::Frame::MAX_STANDARD_ID {
        return Err(error(section, format!("cob_id = {cob_id:#x} is above 0x7FF")));
    }
    let entries: Vec<MapEntry> = config.mapping.iter().map(|&m| MapEntry::from_u32(m)).collect();
    let mapping = PdoMapping::new(&entries).map_err(|e| error(section, e.to_string()))?;
    let value_at = mapping
        .locate(value.0, value.1)
        .ok_or_else(|| error(section, format!("the mapping lacks {:#06x}:{}", value.0, value.1)))?;
    Ok(Pdo {
        cob_id,
        mapping,
        value_at,
    })
}

/// `object` is mapped with its type's width.
fn check_width(section: &str, pdo: &Pdo, object: (u16, u8), bits: u8) -> Result<(), ProfileError> {
    match pdo.mapping.locate(object.0, object.1) {
        Some((_, mapped)) if mapped != bits => Err(error(
            section,
            format!(
                "{:#06x}:{} is mapped with {mapped} bits, its type has {bits}",
                object.0, object.1
            ),
        )),
        _ => Ok(()),
    }
}

fn pressure_channel(section: &str, node: &PressureNode) -> Result<PressureChannel, ProfileError> {
    let scale = node.scale();
    let object = scale.value_type.object();
    let config = node.value.clone().unwrap_or(PdoConfig {
        number: 1,
        cob_id: None,
        mapping: vec![MapEntry::new(object, node.channel, scale.value_type.bits()).to_u32()],
    });
    let value = pdo(
        &format!("{section}.value"),
        &config,
        Direction::Tpdo,
        node.node,
        (object, node.channel),
    )?;
    check_width(section, &value, (object, node.channel), scale.value_type.bits())?;
    Ok(PressureChannel {
        node: node.node,
        scale,
        value,
    })
}

impl Profile {
    /// Every COB-ID the stack sends or receives, named.
    pub(crate) fn cob_ids(&self) -> Vec<(u16, String)> {
        let mut ids = vec![(cob_id::NMT, "NMT".to_string()), (self.sync_cob_id, "SYNC".to_string())];
        let devices = [
            ("valve", self.valve),
            ("encoder", self.encoder),
            ("pressure_a", self.pressure[0].node),
            ("pressure_b", self.pressure[1].node),
        ];
        for (name, node) in devices {
            ids.push((cob_id::emcy(node), format!("{name} EMCY")));
            ids.push((cob_id::heartbeat(node), format!("{name} heartbeat")));
            ids.push((cob_id::sdo_request(node), format!("{name} SDO request")));
            ids.push((cob_id::sdo_response(node), format!("{name} SDO response")));
        }
        ids.push((self.valve_set_point.cob_id, "valve set point RPDO".to_string()));
        ids.push((self.valve_control.cob_id, "valve control RPDO".to_string()));
        ids.push((self.valve_status.cob_id, "valve status TPDO".to_string()));
        ids.push((self.encoder_position.cob_id, "encoder position TPDO".to_string()));
        ids.push((self.pressure[0].value.cob_id, "pressure_a TPDO".to_string()));
        ids.push((self.pressure[1].value.cob_id, "pressure_b TPDO".to_string()));
        ids
    }

    fn check_clashes(&self) -> Result<(), ProfileError> {
        let ids = self.cob_ids();
        for (i, (id, name)) in ids.iter().enumerate() {
            if let Some((_, other)) = ids[i + 1..].iter().find(|(o, _)| o == id) {
                return Err(error(
                    "",
                    format!("COB-ID {id:#05x} is both the {name} and the {other}"),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> CanConfig {
        toml::from_str::<CanConfig>(text).expect("toml")
    }

    #[test]
    fn the_defaults_resolve_to_the_predefined_connection_set() {
        let profile = CanConfig::default().resolve().expect("defaults");
        assert_eq!(profile.valve_set_point.cob_id, 0x210);
        assert_eq!(profile.valve_set_point.value_at, (2, 16));
        assert_eq!(profile.valve_control.cob_id, 0x310);
        assert_eq!(profile.valve_status.cob_id, 0x190);
        assert_eq!(profile.valve_status_word_at, (0, 16));
        assert_eq!(profile.encoder_position.cob_id, 0x1A0);
        assert_eq!(profile.pressure[0].value.cob_id, 0x1B0);
        assert_eq!(profile.pressure[1].value.cob_id, 0x1B1);
        assert_eq!(profile.pressure[1].value.mapping.entries()[0].to_u32(), 0x7130_0110);
    }

    #[test]
    fn a_period_fits_at_one_megabit_and_not_at_five_hundred_kilobit() {
        let fast = CanConfig::default().resolve().expect("1 Mbit/s").budget(1_000_000);
        assert!(fast.fits, "{}", fast.table());
        assert!(
            fast.load_percent_max > 40.0 && fast.load_percent_max < 60.0,
            "{}",
            fast.table()
        );
        let slow = CanConfig {
            bitrate: 500_000,
            ..CanConfig::default()
        }
        .resolve()
        .expect("500 kbit/s")
        .budget(1_000_000);
        assert!(!slow.fits, "{}", slow.table());
        assert!(slow.table().contains("does not fit"));
        let quarter = CanConfig {
            bitrate: 250_000,
            ..CanConfig::default()
        }
        .resolve()
        .expect("250 kbit/s")
        .budget(1_000_000);
        assert!(
            quarter.shortest_period_us > 2000.0 && quarter.shortest_period_us < 3000.0,
            "{}",
            quarter.table()
        );
    }

    #[test]
    fn clashes_and_bad_mappings_are_named() {
        let clash = parse("[pressure_b]\nnode = 0x30\n").resolve().expect_err("same node");
        assert_eq!(
            clash.to_string(),
            "[can] [can.pressure_a] and [can.pressure_b] are both node 48"
        );
        let cob = parse("[valve.status]\nnumber = 1\ncob_id = 0x1A0\nmapping = [0x60410010, 0x63010110]\n")
            .resolve()
            .expect_err("cob clash");
        assert_eq!(
            cob.to_string(),
            "[can] COB-ID 0x1a0 is both the valve status TPDO and the encoder position TPDO"
        );
        let lacking = parse("[valve.set_point]\nnumber = 1\nmapping = [0x00030010]\n")
            .resolve()
            .expect_err("no set point");
        assert_eq!(lacking.to_string(), "[can.valve.set_point] the mapping lacks 0x6300:1");
        let narrow = parse("[valve.set_point]\nnumber = 1\nmapping = [0x00030010, 0x63000108]\n")
            .resolve()
            .expect_err("8-bit set point");
        assert_eq!(
            narrow.to_string(),
            "[can.valve.set_point] 0x6300:1 is mapped with 8 bits, its type has 16"
        );
        let node = parse("[encoder]\nnode = 0\n").resolve().expect_err("node 0");
        assert!(node.to_string().starts_with("[can.encoder] node = 0"), "{node}");
        assert!(
            toml::from_str::<CanConfig>("[valve]\nnod = 3\n").is_err(),
            "unknown keys refused"
        );
        assert!(
            toml::from_str::<CanConfig>("[encoder]\ncounts = 3\n").is_err(),
            "unknown keys refused"
        );
        assert!(
            toml::from_str::<CanConfig>("[pressure_a]\nunits = \"bar\"\n").is_err(),
            "unknown keys refused"
        );
        let heartbeat = parse("heartbeat_ms = 100\nheartbeat_timeout_ms = 50\n")
            .resolve()
            .expect_err("timeout");
        assert!(heartbeat.to_string().contains("heartbeat_timeout_ms"), "{heartbeat}");
    }

    #[test]
    fn scaling_and_mappings_come_from_the_table() {
        let config = parse(
            "bitrate = 500000\n[encoder]\ncounts_per_revolution = 4096\nzero_count = 12\n\
             [pressure_a]\nvalue_type = \"real32\"\ndecimal_digits = 0\nunit = \"MPa\"\n",
        );
        let profile = config.resolve().expect("profile");
        assert_eq!(profile.bitrate, 500_000);
        assert_eq!(profile.encoder_scale.counts_per_revolution, 4096);
        assert_eq!(profile.encoder_scale.zero_count, 12);
        assert_eq!(profile.pressure[0].value.mapping.entries()[0].to_u32(), 0x6130_0120);
        assert_eq!(profile.pressure[0].value.mapping.len(), 4);
    }
}
