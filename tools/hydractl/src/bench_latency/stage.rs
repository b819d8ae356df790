//! One stage of `hydractl bench latency` as its own process: the stage's
//! real algorithm applied to the benchmark's sample, over the transport
//! the driver names.

use std::net::UdpSocket;
use std::path::PathBuf;

use super::semaphore_service::{self, SemaphoreInlet, SemaphoreOutlet};
use anyhow::{bail, Context, Result};
use hydractl_bus::{clock, quiet_ipc_logging, Bus, Inlet, Outlet, RunScope, Wakeup};
use hydractl_config::Config;
use hydractl_plant::RawReading;
use hydractl_samples::BenchSample;
use hydractl_stages::{
    FrictionOutput, FrictionStage, PositionOutput, PositionStage, SensorEstimate, SensorStage, TorqueStage, ValveStage,
};

use super::{udp_addresses, SERVICES, STAGES};

#[derive(clap::Args)]
pub struct StageArgs {
    #[arg(long)]
    index: usize,
    #[arg(long)]
    transport: String,
    /// UDP: the port of the next hop.
    #[arg(long)]
    next_port: Option<u16>,
    /// UDP: the observers' ports, each sent every output too.
    #[arg(long, value_delimiter = ',')]
    observer_ports: Vec<u16>,
    #[arg(long)]
    config: Option<PathBuf>,
}

/// One stage's algorithm, applied to the benchmark sample.
// One per stage process, built once; boxing would only add an indirection.
#[allow(clippy::large_enum_variant)]
pub(super) enum Stage {
    Sensor(SensorStage),
    Friction(FrictionStage),
    Position(PositionStage, f64),
    Torque(TorqueStage),
    Valve(ValveStage),
}

impl Stage {
    pub(super) fn new(index: usize, config: &Config) -> Result<Self> {
        Ok(match index {
            0 => Stage::Sensor(SensorStage::new(config)?),
            1 => Stage::Friction(FrictionStage::new(config)?),
            2 => Stage::Position(PositionStage::new(config)?, config.timing.control_period()),
            3 => Stage::Torque(TorqueStage::new(config)?),
            4 => Stage::Valve(ValveStage::new(config)?),
            _ => bail!("stage index {index} is not 0–4"),
        })
    }

    pub(super) fn apply(&mut self, s: &mut BenchSample) {
        let estimate = SensorEstimate {
            angle: s.angle,
            velocity: s.velocity,
            p_a: s.p_a,
            p_b: s.p_b,
            torque: s.torque,
        };
        match self {
            Stage::Sensor(stage) => {
                let e = stage.process(&RawReading {
                    angle: s.angle,
                    p_a: s.p_a,
                    p_b: s.p_b,
                });
                s.velocity = e.velocity;
                s.torque = e.torque;
            }
            Stage::Friction(stage) => {
                s.friction = stage.process(&estimate, s.reference_velocity, s.command).compensation;
            }
            Stage::Position(stage, period) => {
                // The bench's wire sample has no slot for the load's
                // feed-forward: the friction stage computes it all the
                // same, and adding it here would take no time to speak of.
                let friction = FrictionOutput {
                    compensation: s.friction,
                    load_feedforward: 0.0,
                };
                let out = stage.process(s.seq as f64 * *period, &estimate, friction);
                s.reference_velocity = out.reference.velocity;
                s.output = out.output;
            }
            Stage::Torque(stage) => {
                let out = PositionOutput {
                    reference: hydractl_control::Reference {
                        velocity: s.reference_velocity,
                        ..Default::default()
                    },
                    output: s.output,
                };
                s.command = stage.process(&out, &estimate, s.friction);
            }
            Stage::Valve(stage) => s.command = stage.process(s.command),
        }
    }
}

/// A stage process of the benchmark.
pub fn stage(args: StageArgs) -> Result<()> {
    quiet_ipc_logging();
    let config = Config::load_or_default(args.config.as_deref())?;
    for e in hydractl_rt::enter_loop(config.timing.loop_cpu, config.timing.realtime_priority) {
        tracing::warn!("{e}");
    }
    let mut stage = Stage::new(args.index, &config)?;
    let stamp = args.index + 1;
    match args.transport.as_str() {
        "iceoryx2" | "iceoryx2-events" => {
            let wakeup = match args.transport.as_str() {
                "iceoryx2" => Wakeup::Doorbell,
                _ => Wakeup::Event,
            };
            let scope = RunScope::from_env()?;
            let bus = Bus::open(&scope, &format!("bench-{}", STAGES[args.index]))?;
            let input: Inlet<BenchSample> = Inlet::open_waking(&bus, SERVICES[args.index], 4, wakeup)?;
            let output: Outlet<BenchSample> = Outlet::open_waking(&bus, SERVICES[args.index + 1], wakeup)?;
            crate::emit("ready\n")?;
            let mut failure = None;
            let mut on_input = || {
                hydractl_bus::guarded(&mut failure, || -> Result<()> {
                    while let Some(mut s) = input.next()? {
                        stage.apply(&mut s);
                        s.stamps_ns[stamp] = clock::now_ns();
                        output.publish(s)?;
                    }
                    Ok(())
                })
            };
            hydractl_bus::run_single(input.input(), &bus, &mut on_input)?;
            failure.map_or(Ok(()), Err)
        }
        "iceoryx2-sem" => {
            let scope = RunScope::from_env()?;
            let node = semaphore_service::open_node(&scope)?;
            let input: SemaphoreInlet<BenchSample> = SemaphoreInlet::open(&node, SERVICES[args.index])?;
            let output: SemaphoreOutlet<BenchSample> = SemaphoreOutlet::open(&node, SERVICES[args.index + 1])?;
            crate::emit("ready\n")?;
            // The benchmark kills its stages when it is done.
            loop {
                input.wait()?;
                while let Some(mut s) = input.next()? {
                    stage.apply(&mut s);
                    s.stamps_ns[stamp] = clock::now_ns();
                    output.publish(s)?;
                }
            }
        }
        "udp" => {
            let socket = UdpSocket::bind("127.0.0.1:0")?;
            let next = args.next_port.context("--next-port is needed for udp")?;
            socket.connect(("127.0.0.1", next))?;
            let observers = udp_addresses(&args.observer_ports);
            let input = UdpSocket::bind("127.0.0.1:0")?;
            crate::emit(&format!("{}\n", input.local_addr()?.port()))?;
            let mut buf = [0u8; BenchSample::WIRE_SIZE];
            loop {
                let n = match input.recv(&mut buf) {
                    Ok(n) => n,
                    // SIGTERM ends the benchmark's stages.
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return Ok(()),
                    Err(e) => return Err(e.into()),
                };
                if n != BenchSample::WIRE_SIZE {
                    continue;
                }
                let mut s = BenchSample::from_bytes(&buf);
                stage.apply(&mut s);
                s.stamps_ns[stamp] = clock::now_ns();
                let bytes = s.to_bytes();
                socket.send(&bytes)?;
                for observer in &observers {
                    socket.send_to(&bytes, observer)?;
                }
            }
        }
        other => bail!("unknown transport `{other}`: iceoryx2, iceoryx2-events, iceoryx2-sem or udp"),
    }
}
