//! The machine on the virtual CAN bus, for a run whose `[can]` transport
//! is `virtual`: the wire and the simulated ECUs as processes of their own.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{RunScope, PREFIX_ENV};

use super::stop_child;

/// The machine on the virtual CAN bus: the bus's wire (`canbus`) and the
/// simulated ECUs (`ecus`), stopped in the reverse order when dropped.
pub(super) struct VirtualMachine {
    children: Vec<(Child, &'static str)>,
}

impl VirtualMachine {
    pub(super) fn start(scope: &RunScope, dir: &Path, config: Option<&Path>) -> Result<Self> {
        let mut machine = Self { children: Vec::new() };
        for name in ["canbus", "ecus"] {
            let mut command = Command::new(dir.join(name));
            if let Some(config) = config {
                command.arg("--config").arg(config);
            }
            let child = command
                .env(PREFIX_ENV, scope.prefix())
                .stdin(Stdio::null())
                .spawn()
                .with_context(|| format!("starting {}", dir.join(name).display()))?;
            machine.children.push((child, name));
            // The wire first: a frame sent before it listens is lost.
            let deadline = Instant::now() + Duration::from_secs(5);
            while !scope.live_node_names()?.iter().any(|n| n == name) {
                if let Some((child, _)) = machine.children.last_mut() {
                    if let Some(status) = child.try_wait()? {
                        bail!("{name} ended at start ({status})");
                    }
                }
                if Instant::now() >= deadline {
                    bail!("{name} did not open its node within 5 s");
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        Ok(machine)
    }
}

impl Drop for VirtualMachine {
    fn drop(&mut self) {
        for (child, name) in self.children.iter_mut().rev() {
            // Nothing is left to report to: the run's result is out.
            let _ = stop_child(child, name, Duration::from_secs(2));
        }
    }
}
