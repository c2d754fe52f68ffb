//! `b2tf bop eval`: BOP'19 AR of a results CSV, as a table or JSON.

use crate::bop::evaluate::evaluate;
use crate::bop::results_csv::read_results;
use crate::bop::scoring::{format_report, Bop19Params};
use crate::render::RenderPool;
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Dataset root (models/, test/, test_targets_bop19.json).
    #[arg(long)]
    pub dataset: PathBuf,
    /// BOP results CSV (scene_id,im_id,obj_id,score,R,t,time).
    #[arg(long)]
    pub results: PathBuf,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// VSD visibility tolerance in mm (BOP'19: 15; 5 for ITODD).
    #[arg(long, default_value_t = 15.0)]
    pub vsd_delta: f64,
}

pub fn run(a: EvalArgs) -> Result<()> {
    // What the files hold that the toolkit accepts but is worth a look (rotations that are
    // rotations only roughly), printed once the progress bar is gone.
    let mut warnings = Vec::new();
    let results = read_results(&a.results, &mut warnings)?;
    let pool = super::open_renderer(RenderPool::DEFAULT_SIZE)?;
    let params = Bop19Params { vsd_delta: a.vsd_delta, ..Default::default() };
    let pb = super::progress::bar(0, "targets");
    let progress = |done: usize, total: usize| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    };
    let report = evaluate(&a.dataset, &a.split, &results, &pool, &params, &progress, &mut warnings)?;
    pb.finish_and_clear();
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let seconds: Vec<f64> = {
            let mut per_image: std::collections::BTreeMap<(u32, u32), f64> = Default::default();
            for r in &results {
                per_image.insert((r.scene_id, r.im_id), r.time);
            }
            per_image.into_values().collect()
        };
        let mean = if seconds.is_empty() { 0.0 } else { seconds.iter().sum::<f64>() / seconds.len() as f64 };
        println!("{}: {} estimates over {} images, mean {:.2} s per image", a.results.display(), results.len(), seconds.len(), mean);
        print!("{}", format_report(&report));
    }
    Ok(())
}
