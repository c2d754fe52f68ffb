use clap::Parser;

fn main() {
    // Before any thread starts (it sets an environment variable).
    b2tfpose::render::quiet_headless_vulkan_loader();
    // Named, so that per-thread CPU (`bench serve`, top, /proc) tells the global pool's
    // workers from the backbone's, tokio's and the libraries' threads.
    let _ = rayon::ThreadPoolBuilder::new().thread_name(|i| format!("rayon-{i}")).build_global();
    let cli = b2tfpose::cli::Cli::parse();
    let telemetry = match b2tfpose::telemetry::init(&cli.telemetry, cli.command.default_log_filter()) {
        Ok(g) => g,
        Err(e) => {
            b2tfpose::telemetry::fatal(&b2tfpose::telemetry::error_text(&e));
            std::process::exit(2);
        }
    };
    if let Err(e) = b2tfpose::cli::run(cli) {
        b2tfpose::telemetry::fatal(&b2tfpose::telemetry::error_text(&e));
        telemetry.flush();
        std::process::exit(1);
    }
}
