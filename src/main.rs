//! The `harmap` command. All the work is in the library and `src/cli/`.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
