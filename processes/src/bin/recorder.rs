//! The recorder: every sample of the run into an MCAP file. See [`hydractl_processes::process::recorder`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::recorder::run()
}
