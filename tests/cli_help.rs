//! Every option of every subcommand (of `fascicle` and `fascicle-bench`) explains itself: clap's own model of
//! the command line is walked, and each subcommand's `--help` output is read back for each option and its text.

use std::process::Command;

use clap::CommandFactory;

/// (path of subcommand names, long flag or positional name) of every argument that has no help text.
fn undocumented(cmd: &clap::Command, path: &mut Vec<String>, out: &mut Vec<String>) {
    for arg in cmd.get_arguments() {
        let id = arg.get_id().as_str();
        if matches!(id, "help" | "version") {
            continue;
        }
        if arg.get_help().is_none() && arg.get_long_help().is_none() {
            out.push(format!("{} {}", path.join(" "), arg.get_long().map_or(id.to_string(), |l| format!("--{l}"))));
        }
    }
    for sub in cmd.get_subcommands() {
        if sub.get_name() == "help" {
            continue;
        }
        if sub.get_about().is_none() {
            out.push(format!("{} {} (no description)", path.join(" "), sub.get_name()));
        }
        path.push(sub.get_name().to_string());
        undocumented(sub, path, out);
        path.pop();
    }
}

/// A leaf subcommand's path and its (long flag, help) pairs.
type Leaf = (Vec<String>, Vec<(String, String)>);

/// Every leaf subcommand's path.
fn leaves(cmd: &clap::Command, path: &mut Vec<String>, out: &mut Vec<Leaf>) {
    let subs: Vec<_> = cmd.get_subcommands().filter(|s| s.get_name() != "help").collect();
    if subs.is_empty() {
        let args = cmd
            .get_arguments()
            .filter_map(|a| Some((a.get_long()?.to_string(), a.get_help()?.to_string())))
            .filter(|(l, _)| l != "help" && l != "version")
            .collect();
        out.push((path.clone(), args));
    }
    for sub in subs {
        path.push(sub.get_name().to_string());
        leaves(sub, path, out);
        path.pop();
    }
}

#[test]
fn every_option_has_help() {
    let mut missing = Vec::new();
    undocumented(&fascicle::cli::Cli::command(), &mut vec!["fascicle".into()], &mut missing);
    assert!(missing.is_empty(), "options without help text:\n{}", missing.join("\n"));

    // The same seen from outside: each subcommand's --help lists every option with the first words of its help.
    let mut all = Vec::new();
    leaves(&fascicle::cli::Cli::command(), &mut Vec::new(), &mut all);
    assert!(all.len() >= 9, "{} subcommands", all.len());
    for (path, args) in all {
        let o = Command::new(env!("CARGO_BIN_EXE_fascicle")).args(&path).arg("--help").output().unwrap();
        assert!(o.status.success(), "{path:?} --help");
        let text = String::from_utf8_lossy(&o.stdout);
        for (long, help) in args {
            let flag = format!("--{long} ");
            let line = text
                .lines()
                .find(|l| {
                    let t = l.trim_start();
                    t.starts_with(&flag)
                        || t.starts_with(&format!("--{long}\n"))
                        || t == format!("--{long}")
                        || (t.starts_with('-') && t.contains(&format!(", {flag}")))
                        || (t.starts_with('-') && t.ends_with(&format!(", --{long}")))
                })
                .unwrap_or_else(|| panic!("{path:?}: --{long} not in --help:\n{text}"));
            let first: String = help.split_whitespace().take(2).collect::<Vec<_>>().join(" ");
            let after = text.split(line).nth(1).unwrap_or("");
            assert!(
                line.contains(&first) || after.lines().take(3).any(|l| l.contains(&first)),
                "{path:?} --{long}: help '{first}' not shown:\n{text}"
            );
        }
    }
}
