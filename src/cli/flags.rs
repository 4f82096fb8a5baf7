//! `harmap flags` (hidden): every stage command's long flags and their defaults as
//! JSON, read from the parser itself, so the Python package's tests can check that its
//! keyword arguments are the command line's, with the same defaults.

use clap::CommandFactory;
use serde_json::{json, Map, Value};

/// Print the long flags of `harmap run` and of every stage command, as JSON: for each
/// command, each flag with its default (null when it has none) and whether it is an
/// on/off switch.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Run `harmap flags`.
pub fn run(_: &Args, _: &super::Global) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(&flags())?);
    Ok(())
}

/// The flags of the commands that run stages, by command.
#[must_use]
pub fn flags() -> Value {
    let cli = super::Cli::command();
    let mut out = Map::new();
    for name in [
        "run", "voxelize", "solve", "trace", "map", "inverse", "export",
    ] {
        let Some(c) = cli.find_subcommand(name) else {
            continue;
        };
        let mut m = Map::new();
        for a in c.get_arguments() {
            let Some(long) = a.get_long() else {
                continue;
            };
            let defaults: Vec<String> = a
                .get_default_values()
                .iter()
                .map(|v| v.to_string_lossy().into_owned())
                .collect();
            m.insert(
                long.to_owned(),
                json!({
                    "default": if defaults.is_empty() { Value::Null } else { json!(defaults.join(",")) },
                    "switch": !a.get_action().takes_values(),
                }),
            );
        }
        out.insert(name.to_owned(), Value::Object(m));
    }
    Value::Object(out)
}
