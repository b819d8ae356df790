//! The command-line reference (`tools/hydractl/README.md`) agrees with the
//! program: every command and every flag the program takes is in it.

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    use crate::Cli;

    /// Every command path (`hydractl model diagnose`) and each of its long
    /// flags, as clap knows them.
    fn commands(command: &clap::Command, path: &str, out: &mut Vec<(String, Vec<String>)>) {
        let flags = command
            .get_arguments()
            .filter(|a| !a.is_global_set() && !a.is_hide_set())
            .filter_map(|a| a.get_long().map(|l| format!("--{l}")))
            .filter(|l| l != "--help" && l != "--version")
            .collect();
        out.push((path.to_owned(), flags));
        for sub in command
            .get_subcommands()
            .filter(|s| s.get_name() != "help" && !s.is_hide_set())
        {
            commands(sub, &format!("{path} {}", sub.get_name()), out);
        }
    }

    #[test]
    fn every_command_and_flag_is_in_the_reference() {
        let reference = include_str!("../README.md");
        let mut all = Vec::new();
        commands(&Cli::command(), "hydractl", &mut all);
        let mut missing = Vec::new();
        for (path, flags) in &all {
            if !reference.contains(path.as_str()) {
                missing.push(path.clone());
            }
            // A flag is documented in its command's section, from its
            // heading (or usage line) to the next command's.
            let top = path.split(' ').take(2).collect::<Vec<_>>().join(" ");
            let section = reference
                .find(&format!("## `{top}"))
                .map(|start| {
                    let rest = &reference[start + 3..];
                    &rest[..rest.find("\n## ").unwrap_or(rest.len())]
                })
                .unwrap_or(reference);
            for flag in flags {
                if !section.contains(flag.as_str()) {
                    missing.push(format!("{path} {flag}"));
                }
            }
        }
        assert!(
            missing.is_empty(),
            "not in tools/hydractl/README.md:\n{}",
            missing.join("\n")
        );
    }
}
