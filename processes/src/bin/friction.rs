//! The friction stage: the crane paper's friction compensation (eq. 1). See [`hydractl_processes::process::friction`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::friction::run()
}
