use clap::Parser;

fn main() {
    let cli = b2tfpose::cli::Cli::parse();
    if let Err(e) = b2tfpose::cli::run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
