//! The `phasekit` command (filled by the CLI issue).

fn main() {
    eprintln!("phasekit: the command-line interface is not built yet; see the README");
    std::process::exit(2);
}
