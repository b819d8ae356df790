//! The master's side of the machine's devices, as the sensor and valve
//! processes run it: plain state driven by frames and the clock, no I/O.
//!
//! - [`SensorMaster`]: the SYNC producer and PDO consumer. Each period it
//!   starts with a SYNC, gathers the encoder's and transducers' TPDOs that
//!   answer it, and watches the three nodes' heartbeats; a value that has
//!   not come is NaN, never the previous period's.
//! - [`ValveMaster`]: brings the valve up (NMT start, its own timeout and
//!   heartbeat written by SDO and read back, the control-word sequence to
//!   Active), builds the set point RPDO (neutral in every state but
//!   Active), and reads the valve's status TPDO, EMCYs and heartbeat. It
//!   never clears a fault by itself: [`ValveMaster::reset_frames`] is for a
//!   person's reset.

use crate::canopen::{self, cob_id, Emergency, NmtCommand, NmtState, NodeId, SdoResponse};
use crate::ecu::{RPDO_COMMUNICATION, RPDO_EVENT_TIMER};
use crate::heartbeat::{set_heartbeat, HeartbeatWatch, HEARTBEAT_PRODUCER};
use crate::profile::{Pdo, PressureChannel, Profile};
use crate::settings::{Setting, SettingsCheck};
use crate::valve::{self, DeviceState};
use crate::{CanError, Frame};

/// One period's sensor values: NaN for a PDO that did not come.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorValues {
    pub angle: f64,
    pub p_a: f64,
    pub p_b: f64,
}

impl SensorValues {
    const MISSING: Self = Self {
        angle: f64::NAN,
        p_a: f64::NAN,
        p_b: f64::NAN,
    };
}

/// What the sensor master made of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorFrame {
    /// One of this period's values.
    Value,
    /// A heartbeat (or boot-up) of one of the sensor nodes.
    Heartbeat(NodeId),
    /// Not for the sensor master.
    Other,
}

pub struct SensorMaster {
    sync_cob_id: u16,
    encoder: Pdo,
    /// The node, not derived from the PDO's COB-ID (which a config may move).
    encoder_node: NodeId,
    encoder_scale: crate::encoder::EncoderScale,
    pressure: [PressureChannel; 2],
    /// Encoder, transducer A, transducer B.
    heartbeats: [HeartbeatWatch; 3],
    heartbeat_ms: u16,
    values: SensorValues,
    /// Bit per value gathered this period: encoder, A, B.
    gathered: u8,
    bad_pdos: u64,
    sync_counter: u8,
}

const ALL_GATHERED: u8 = 0b111;

impl SensorMaster {
    pub fn new(profile: &Profile) -> Self {
        let watch = |node| HeartbeatWatch::new(node, profile.heartbeat_timeout_ms);
        Self {
            sync_cob_id: profile.sync_cob_id,
            encoder: profile.encoder_position,
            encoder_node: profile.encoder,
            encoder_scale: profile.encoder_scale,
            pressure: profile.pressure,
            heartbeats: [
                watch(profile.encoder),
                watch(profile.pressure[0].node),
                watch(profile.pressure[1].node),
            ],
            heartbeat_ms: profile.heartbeat_ms,
            values: SensorValues::MISSING,
            gathered: 0,
            bad_pdos: 0,
            sync_counter: 0,
        }
    }

    /// The sensor nodes' IDs: encoder, transducer A, transducer B.
    pub fn nodes(&self) -> [NodeId; 3] {
        [
            self.heartbeats_node(0),
            self.heartbeats_node(1),
            self.heartbeats_node(2),
        ]
    }

    fn heartbeats_node(&self, i: usize) -> NodeId {
        match i {
            0 => self.encoder_node(),
            _ => self.pressure[i - 1].node,
        }
    }

    fn encoder_node(&self) -> NodeId {
        self.encoder_node
    }

    /// What brings each sensor node up: its heartbeat producer time set by
    /// SDO (a device ships with its own, the PVED-CC with 1000 ms: longer
    /// than the consumer's timeout), then NMT start (not for all nodes: the
    /// valve is the valve process's to start).
    pub fn start_frames(&self) -> [Frame; 6] {
        let [a, b, c] = self.nodes();
        [
            set_heartbeat(a, self.heartbeat_ms),
            set_heartbeat(b, self.heartbeat_ms),
            set_heartbeat(c, self.heartbeat_ms),
            canopen::nmt(NmtCommand::Start, a),
            canopen::nmt(NmtCommand::Start, b),
            canopen::nmt(NmtCommand::Start, c),
        ]
    }

    /// A new period: forgets the last one's values and returns its SYNC.
    pub fn sync(&mut self) -> Frame {
        self.values = SensorValues::MISSING;
        self.gathered = 0;
        self.sync_counter = self.sync_counter.wrapping_add(1);
        canopen::sync(self.sync_cob_id, None)
    }

    /// Takes a frame from the bus. A PDO of the wrong length is counted
    /// and returned as the error that names its COB-ID; the value stays
    /// missing.
    pub fn on_frame(&mut self, frame: &Frame, now_ns: u64) -> Result<SensorFrame, CanError> {
        if frame.is_error() || frame.is_extended() || frame.is_remote() {
            return Ok(SensorFrame::Other);
        }
        for (i, watch) in self.heartbeats.iter_mut().enumerate() {
            if watch.on_frame(frame, now_ns) {
                return Ok(SensorFrame::Heartbeat(match i {
                    0 => self.encoder_node,
                    _ => self.pressure[i - 1].node,
                }));
            }
        }
        let id = frame.id as u16;
        if id == self.encoder.cob_id {
            let raw = self.read(self.encoder, frame, "encoder position TPDO")?;
            self.values.angle = self.encoder_scale.angle(raw as u32);
            self.gathered |= 0b001;
            return Ok(SensorFrame::Value);
        }
        for i in 0..2 {
            let channel = self.pressure[i];
            if id == channel.value.cob_id {
                let raw = self.read(channel.value, frame, "pressure TPDO")?;
                let pascal = channel.scale.pascal(raw)?;
                if i == 0 {
                    self.values.p_a = pascal;
                } else {
                    self.values.p_b = pascal;
                }
                self.gathered |= 0b010 << i;
                return Ok(SensorFrame::Value);
            }
        }
        Ok(SensorFrame::Other)
    }

    fn read(&mut self, pdo: Pdo, frame: &Frame, what: &'static str) -> Result<u64, CanError> {
        pdo.read(frame, what).inspect_err(|_| self.bad_pdos += 1)
    }

    /// Every value of this period has come.
    pub fn complete(&self) -> bool {
        self.gathered == ALL_GATHERED
    }

    /// This period's values, NaN where a PDO has not come.
    pub fn values(&self) -> SensorValues {
        self.values
    }

    /// How many of this period's three PDOs are missing.
    pub fn missing(&self) -> u32 {
        3 - self.gathered.count_ones()
    }

    pub fn bad_pdos(&self) -> u64 {
        self.bad_pdos
    }

    /// The first sensor node whose heartbeat was heard and then stopped.
    pub fn lost(&self, now_ns: u64) -> Option<NodeId> {
        (0..3)
            .find(|&i| self.heartbeats[i].lost(now_ns))
            .map(|i| self.heartbeats_node(i))
    }

    /// Every sensor node has said it is operational.
    pub fn all_operational(&self) -> bool {
        self.heartbeats.iter().all(|w| w.state() == Some(NmtState::Operational))
    }
}

/// What the valve master made of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValveFrame {
    Status(DeviceState),
    Emergency(Emergency),
    Heartbeat(NmtState),
    /// An answer to the master's SDO request.
    Setting,
    Other,
}

pub struct ValveMaster {
    node: NodeId,
    set_point: Pdo,
    control: Pdo,
    status: Pdo,
    status_word_at: (usize, u8),
    heartbeat: HeartbeatWatch,
    /// The valve's own timeout and heartbeat, as the master wants them.
    wanted: [Setting; 2],
    settings: SettingsCheck<2>,
    state: Option<DeviceState>,
    /// When the last status came, ns.
    status_ns: Option<u64>,
    was_ready: bool,
    actual: f64,
    emcys: u64,
    last_emcy: Option<Emergency>,
    bad_pdos: u64,
}

impl ValveMaster {
    pub fn new(profile: &Profile) -> Self {
        let wanted = [
            Setting {
                index: HEARTBEAT_PRODUCER,
                sub: 0,
                value: profile.heartbeat_ms,
                what: "heartbeat time",
                unit: "ms",
            },
            Setting {
                index: RPDO_COMMUNICATION + u16::from(profile.valve_set_point_rpdo) - 1,
                sub: RPDO_EVENT_TIMER,
                value: profile.valve_rpdo_timeout_ms,
                what: "its own timeout",
                unit: "ms",
            },
        ];
        Self {
            node: profile.valve,
            set_point: profile.valve_set_point,
            control: profile.valve_control,
            status: profile.valve_status,
            status_word_at: profile.valve_status_word_at,
            heartbeat: HeartbeatWatch::new(profile.valve, profile.heartbeat_timeout_ms),
            wanted,
            settings: SettingsCheck::new(profile.valve, wanted),
            state: None,
            status_ns: None,
            was_ready: false,
            actual: f64::NAN,
            emcys: 0,
            last_emcy: None,
            bad_pdos: 0,
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    /// NMT start; its settings follow ([`ValveMaster::setting_frame`]).
    pub fn start_frame(&self) -> Frame {
        canopen::nmt(NmtCommand::Start, self.node)
    }

    /// The valve booted again: the settings it had are gone, to be
    /// written and read back afresh.
    pub fn restart(&mut self) {
        self.settings = SettingsCheck::new(self.node, self.wanted);
    }

    /// The next SDO request of the settings' check, when one is due.
    pub fn setting_frame(&mut self, now_ns: u64) -> Option<Frame> {
        self.settings.due(now_ns)
    }

    /// Why the valve's settings cannot be trusted, once known: it is then
    /// not to be brought to Active.
    pub fn settings_failed(&self) -> Option<&CanError> {
        self.settings.failed()
    }

    pub fn on_frame(&mut self, frame: &Frame, now_ns: u64) -> Result<ValveFrame, CanError> {
        if frame.is_error() || frame.is_extended() || frame.is_remote() {
            return Ok(ValveFrame::Other);
        }
        if self.heartbeat.on_frame(frame, now_ns) {
            return Ok(ValveFrame::Heartbeat(
                self.heartbeat.state().unwrap_or(NmtState::BootUp),
            ));
        }
        let id = frame.id as u16;
        if id == cob_id::sdo_response(self.node) {
            let (_, response) = SdoResponse::decode(frame)?;
            self.settings.on_response(response);
            return Ok(ValveFrame::Setting);
        }
        if id == cob_id::emcy(self.node) {
            let (_, emcy) = Emergency::decode(frame)?;
            if emcy.code != canopen::emcy_code::NO_ERROR {
                self.emcys += 1;
            }
            self.last_emcy = Some(emcy);
            return Ok(ValveFrame::Emergency(emcy));
        }
        if id == self.status.cob_id {
            let values = self
                .status
                .mapping
                .unpack(frame, "valve status TPDO")
                .inspect_err(|_| self.bad_pdos += 1)?;
            let word = values[self.status.slot(self.status_word_at)] as u16;
            let actual = canopen::signed(values[self.status.slot(self.status.value_at)], 16) as i16;
            let state = DeviceState::from_status_word(word, self.was_ready);
            self.was_ready |= word & valve::control_word::RESET_FAULT_BIT != 0;
            self.state = Some(state);
            self.status_ns = Some(now_ns);
            self.actual = valve::spool_position(actual);
            return Ok(ValveFrame::Status(state));
        }
        Ok(ValveFrame::Other)
    }

    /// The valve's state as its last status reported.
    pub fn state(&self) -> Option<DeviceState> {
        self.state
    }

    /// Follows the set point: Active by its last status.
    pub fn active(&self) -> bool {
        self.state == Some(DeviceState::Active)
    }

    /// The spool's position from the last status, NaN before one.
    pub fn actual(&self) -> f64 {
        self.actual
    }

    pub fn emcys(&self) -> u64 {
        self.emcys
    }

    pub fn last_emcy(&self) -> Option<Emergency> {
        self.last_emcy
    }

    pub fn bad_pdos(&self) -> u64 {
        self.bad_pdos
    }

    pub fn lost(&self, now_ns: u64) -> bool {
        self.heartbeat.lost(now_ns)
    }

    /// The set point RPDO for `command` in [-1, 1]: the command in Active,
    /// neutral otherwise (and for NaN).
    pub fn set_point_frame(&self, command: f64) -> Result<Frame, CanError> {
        let command = if self.active() { command } else { 0.0 };
        let mut values = [0u64; 8];
        let n = self.set_point.mapping.entries().len();
        values[self.set_point.slot(self.set_point.value_at)] = valve::raw_i16(valve::set_point(command));
        self.set_point.mapping.pack(self.set_point.cob_id, &values[..n])
    }

    /// When the last status came, ns.
    pub fn status_time_ns(&self) -> Option<u64> {
        self.status_ns
    }

    /// The control RPDO that moves the valve one step towards Active from
    /// its last reported state, device mode on the bus. `None` once Active,
    /// before its settings are verified, and in a fault state: the master
    /// never clears a fault by itself.
    pub fn bring_up_frame(&mut self) -> Result<Option<Frame>, CanError> {
        let state = self.state.unwrap_or(DeviceState::NotReady);
        if state == DeviceState::Active || !self.settings.verified() {
            return Ok(None);
        }
        match valve::next_control_word(state) {
            Some(word) => self.control_frame(word).map(Some),
            None => Ok(None),
        }
    }

    /// A person's fault reset: R low, then high, the spool kept at neutral.
    pub fn reset_frames(&mut self) -> Result<[Frame; 2], CanError> {
        let [low, high] = valve::RESET_WORDS;
        Ok([self.control_frame(low)?, self.control_frame(high)?])
    }

    /// The control RPDO that holds the spool at neutral (a master leaving).
    pub fn hold_frame(&mut self) -> Result<Frame, CanError> {
        self.control_frame(valve::control_word::HOLD)
    }

    fn control_frame(&mut self, word: u16) -> Result<Frame, CanError> {
        let mut values = [0u64; 8];
        let n = self.control.mapping.entries().len();
        values[self.control.slot(self.control.value_at)] = u64::from(word);
        if let Some(at) = self.control.mapping.locate(valve::object::DEVICE_MODE, 0) {
            values[self.control.slot((at.0, at.1))] = u64::from(valve::object::DEVICE_MODE_BUS);
        }
        self.control.mapping.pack(self.control.cob_id, &values[..n])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ecu::{Outbox, SensorEcu, ValveEcu};
    use crate::profile::CanConfig;

    const MS: u64 = 1_000_000;

    fn profile() -> Profile {
        CanConfig::default().resolve().expect("defaults")
    }

    type Ecu<'a> = &'a mut dyn FnMut(&Frame, &mut Outbox);

    /// Hands `frames` to each ECU and returns everything they answered.
    fn exchange(ecus: &mut [Ecu<'_>], frames: &[Frame]) -> Vec<Frame> {
        let mut heard = Vec::new();
        for f in frames {
            for ecu in ecus.iter_mut() {
                let mut out = Outbox::default();
                ecu(f, &mut out);
                heard.extend_from_slice(out.frames());
            }
        }
        heard
    }

    #[test]
    fn the_sensor_master_gathers_one_period_and_marks_what_did_not_come() {
        let profile = profile();
        let mut master = SensorMaster::new(&profile);
        let mut encoder = SensorEcu::encoder(&profile);
        let mut pa = SensorEcu::transducer(&profile, &profile.pressure[0]);
        let mut pb = SensorEcu::transducer(&profile, &profile.pressure[1]);
        encoder.measure(u64::from(profile.encoder_scale.position(0.5)));
        pa.measure(profile.pressure[0].scale.raw(10e6));
        pb.measure(profile.pressure[1].scale.raw(3e6));
        for start in master.start_frames() {
            let mut out = Outbox::default();
            for ecu in [&mut encoder, &mut pa, &mut pb] {
                ecu.on_frame(&start, &mut out);
            }
        }
        let sync = master.sync();
        let heard = exchange(
            &mut [
                &mut |f, o| encoder.on_frame(f, o),
                &mut |f, o| pa.on_frame(f, o),
                &mut |f, o| pb.on_frame(f, o),
            ],
            &[sync],
        );
        assert_eq!(heard.len(), 3);
        // Transducer B's PDO is lost this period.
        for f in &heard[..2] {
            assert_eq!(master.on_frame(f, MS), Ok(SensorFrame::Value));
        }
        assert!(!master.complete());
        assert_eq!(master.missing(), 1);
        let v = master.values();
        assert!((v.angle - 0.5).abs() <= profile.encoder_scale.resolution());
        assert!((v.p_a - 10e6).abs() <= profile.pressure[0].scale.resolution());
        assert!(v.p_b.is_nan(), "missing, not the last period's");
        assert_eq!(master.on_frame(&heard[2], MS), Ok(SensorFrame::Value));
        assert!(master.complete());
        // The next period forgets this one's values.
        master.sync();
        assert!(master.values().angle.is_nan());
        // A PDO of the wrong length is refused, naming its COB-ID.
        let short = Frame::new(profile.encoder_position.cob_id, &[1, 2]).expect("frame");
        let e = master.on_frame(&short, MS).expect_err("wrong length");
        assert!(e.to_string().contains("0x1a0"), "{e}");
        assert_eq!(master.bad_pdos(), 1);
        assert!(master.values().angle.is_nan());
    }

    #[test]
    fn the_sensor_master_finds_a_silent_node() {
        let profile = profile();
        let mut master = SensorMaster::new(&profile);
        for node in master.nodes() {
            let hb = canopen::heartbeat(node, NmtState::Operational);
            assert_eq!(master.on_frame(&hb, 0), Ok(SensorFrame::Heartbeat(node)));
        }
        assert!(master.all_operational());
        assert_eq!(master.lost(250 * MS), None);
        for node in [profile.pressure[0].node, profile.pressure[1].node] {
            let hb = canopen::heartbeat(node, NmtState::Operational);
            master.on_frame(&hb, 300 * MS).expect("heartbeat");
        }
        assert_eq!(master.lost(301 * MS), Some(profile.encoder), "the encoder went silent");
    }

    /// One period of master and valve: the master's frames (its due SDO
    /// request first), then the SYNC the status answers.
    fn valve_period(master: &mut ValveMaster, ecu: &mut ValveEcu, frames: &[Frame], now: u64) {
        let sync = canopen::sync(profile().sync_cob_id, None);
        let mut out = Outbox::default();
        ecu.tick(now, &mut out);
        let setting = master.setting_frame(now);
        for f in setting.iter().chain(frames).chain([&sync]) {
            ecu.on_frame(f, now, &mut out);
        }
        for f in out.frames() {
            master.on_frame(f, now).expect("valve frame");
        }
    }

    /// Periods of `command` with the bring-up's steps, up to `periods`.
    fn bring_up(master: &mut ValveMaster, ecu: &mut ValveEcu, now: &mut u64, command: f64, periods: usize) {
        for _ in 0..periods {
            if master.active() {
                break;
            }
            *now += MS;
            let mut frames = vec![master.set_point_frame(command).expect("set point")];
            frames.extend(master.bring_up_frame().expect("control"));
            valve_period(master, ecu, &frames, *now);
        }
    }

    #[test]
    fn the_valve_master_verifies_the_valves_guard_brings_it_up_and_never_resets_a_fault_itself() {
        let profile = profile();
        let mut master = ValveMaster::new(&profile);
        let mut ecu = ValveEcu::new(&profile);
        let mut now = 0;
        let start = [master.start_frame()];
        valve_period(&mut master, &mut ecu, &start, now);
        bring_up(&mut master, &mut ecu, &mut now, 0.5, 12);
        assert_eq!(master.state(), Some(DeviceState::Active));
        assert!(master.settings_failed().is_none());
        assert_eq!(ecu.spool_command(), 0.0, "neutral until the master saw Active");
        now += MS;
        let frames = [master.set_point_frame(0.5).expect("sp")];
        valve_period(&mut master, &mut ecu, &frames, now);
        assert!((ecu.spool_command() - 0.5).abs() < 1e-3);
        assert!(master.bring_up_frame().expect("none").is_none());
        // The master is away longer than the RPDO timeout it wrote.
        now += 30 * MS;
        valve_period(&mut master, &mut ecu, &[], now);
        assert_eq!(master.state(), Some(DeviceState::FaultHold));
        assert_eq!(master.emcys(), 1);
        assert_eq!(
            master.last_emcy().map(|e| e.code),
            Some(canopen::emcy_code::VALVE_RPDO_TIMEOUT)
        );
        assert_eq!(
            master.set_point_frame(0.5).expect("sp").data[2..4],
            [0, 0],
            "neutral while not Active"
        );
        bring_up(&mut master, &mut ecu, &mut now, 0.2, 20);
        assert_eq!(
            master.state(),
            Some(DeviceState::FaultHold),
            "the master never resets a fault by itself"
        );
        // A person's reset: R low then high, and the bring-up goes on.
        now += MS;
        let reset = master.reset_frames().expect("reset");
        valve_period(&mut master, &mut ecu, &reset, now);
        assert_eq!(master.state(), Some(DeviceState::Hold));
        bring_up(&mut master, &mut ecu, &mut now, 0.2, 5);
        assert_eq!(master.state(), Some(DeviceState::Active));
    }

    #[test]
    fn a_valve_that_refuses_its_timeout_is_never_brought_to_active() {
        let profile = profile();
        let mut master = ValveMaster::new(&profile);
        let mut ecu = ValveEcu::new(&profile).with_fixed_timeout(100);
        let mut now = 0;
        let start = [master.start_frame()];
        valve_period(&mut master, &mut ecu, &start, now);
        bring_up(&mut master, &mut ecu, &mut now, 0.5, 30);
        assert_eq!(master.state(), Some(DeviceState::Init), "not a step towards Active");
        let e = master.settings_failed().expect("refused").to_string();
        for part in ["0x10", "0x1400:5", "20 ms", "refused"] {
            assert!(e.contains(part), "{part} in {e}");
        }
    }
}
