use clap::Parser;

fn main() {
    let cli = b2tfpose::cli::Cli::parse();
    let telemetry = match b2tfpose::telemetry::init(&cli.telemetry, cli.command.default_log_filter()) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(2);
        }
    };
    if let Err(e) = b2tfpose::cli::run(cli) {
        eprintln!("error: {e:#}");
        // `exit` runs no destructors: flush the exported spans first.
        drop(telemetry);
        std::process::exit(1);
    }
}
