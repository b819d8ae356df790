//! The machine's CAN devices, as plain functions on frames: no sockets, no
//! clocks, nothing that blocks. The sensor and valve processes, the
//! simulated ECUs and the command line build and read frames only through
//! this crate, so one frame layout has one place.
//!
//! - [`canopen`]: CiA 301, the communication profile every node speaks
//!   (NMT, SYNC, EMCY, heartbeat, expedited SDO, PDOs and their mapping);
//! - [`valve`]: CiA 408, the proportional valve (its device state machine,
//!   set point and spool position);
//! - [`encoder`]: CiA 406, the angle encoder;
//! - [`pressure`]: CiA 404, the pressure transducers;
//! - [`ecu`]: the simulated ECUs (valve, encoder, transducers);
//! - [`heartbeat`]: the producer time a master sets, and its watch of each
//!   node's heartbeat (the consumer);
//! - [`master`]: the master's side: the SYNC producer and PDO consumer,
//!   and the valve's bring-up, set point and status;
//! - [`settings`]: a device's settings written by SDO and read back
//!   before it is trusted (the valve's own timeout, heartbeats);
//! - [`spool`]: the valve's reported spool position against its set
//!   point (stuck, wrong sign);
//! - [`stats`]: a listener's figures of the bus: load, frames per period,
//!   late and lost PDOs, EMCYs, error frames;
//! - [`timing`]: how long a frame occupies the bus, stuffing included, and
//!   whether a period's frames fit;
//! - [`budget`]: what one period's frames take of the bus;
//! - [`candump`]: can-utils' `candump -l` log lines;
//! - [`wire`]: the virtual bus's wire: arbitration, bus time, faults;
//! - [`profile`]: the `[can]` table of the config: nodes, COB-IDs,
//!   mappings, scaling, bitrate and timeouts, checked for clashes.

pub mod budget;
pub mod candump;
pub mod canopen;
pub mod ecu;
pub mod encoder;
mod frame;
pub mod heartbeat;
pub mod master;
pub mod pressure;
pub mod profile;
pub mod settings;
pub mod spool;
pub mod stats;
pub mod timing;
pub mod valve;
pub mod wire;

pub(crate) use frame::error_class;
pub use frame::{CanError, Frame};
