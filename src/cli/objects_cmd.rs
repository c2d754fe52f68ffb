//! `b2tf objects list|show|delete|upgrade|copy`: what an object store holds.

use anyhow::Result;
use clap::{Args, Subcommand};
use std::time::Instant;

#[derive(Args, Debug)]
pub struct ObjectsArgs {
    /// Object store: sqlite://PATH.db, dir://PATH or s3://BUCKET/PREFIX (default: $B2TF_STORE, else
    /// sqlite://~/.local/share/b2tfpose/objects.db).
    #[arg(long, global = true)]
    pub store: Option<String>,
    #[command(subcommand)]
    pub command: ObjectsCommand,
}

#[derive(Subcommand, Debug)]
pub enum ObjectsCommand {
    /// One line per stored object.
    List {
        /// JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// One object's record as JSON; with --load, also loads it whole (checks it decodes).
    Show {
        id: String,
        #[arg(long)]
        load: bool,
    },
    /// Removes an object.
    Delete { id: String },
    /// Brings objects stored by an older version up to the current model format: computes
    /// what they lack (the contour model, the detector's templates) from their stored mesh
    /// and writes them back, without re-onboarding. Default: every object in the store.
    Upgrade {
        ids: Vec<String>,
        /// Also keep the patch rows of objects that hold them per template once per view,
        /// as onboarding does by default with the embedded backbone: several times smaller
        /// on disk and in memory, estimation turning the query instead (docs/store.md,
        /// "Patch rows per view"). With an ONNX backbone each turn is another pass.
        #[arg(long)]
        rows_per_view: bool,
    },
    /// Copies objects into another store, as they are (e.g. from a folder into a bucket
    /// when moving to `s3://`). Default: every object. An object already in the target is
    /// left alone unless --replace.
    Copy {
        /// The store to copy into (dir://, sqlite:// or s3://).
        #[arg(long)]
        to: String,
        ids: Vec<String>,
        #[arg(long)]
        replace: bool,
    },
}

pub fn run(a: ObjectsArgs) -> Result<()> {
    let store = crate::store::open(&a.store.unwrap_or_else(crate::store::default_url))?;
    match a.command {
        ObjectsCommand::List { json } => {
            let list = store.list()?;
            if json {
                println!("{}", serde_json::to_string_pretty(&list)?);
                return Ok(());
            }
            println!("{}: {} objects", store.url(), list.len());
            println!("| id | units | diameter (mm) | backbone | templates | MB | created (unix s) | symmetries |");
            println!("|---|---|---:|---|---:|---:|---:|---|");
            for o in list {
                let symmetries = o.symmetries.as_ref().map_or_else(|| "unknown (objects upgrade finds them)".to_string(), |s| s.describe());
                println!("| {} | {} | {:.1} | {} | {} | {:.1} | {} | {symmetries} |", o.id, o.units.as_str(), o.diameter_m * 1e3, o.backbone.name, o.templates, o.bytes as f64 / 1e6, o.created_at);
            }
        }
        ObjectsCommand::Show { id, load } => {
            let info = store.info(&id)?;
            let mut v = serde_json::to_value(&info)?;
            if load {
                let t = Instant::now();
                let m = store.get(&id)?;
                // How the object is held, which the store's listing does not record.
                let stored =
                    serde_json::json!({"descriptors": m.config.descriptors.to_string(), "pca_components": m.pca.as_ref().map(|p| p.output_dim), "patch_rows": m.config.patch_rows.to_string()});
                v["loaded"] = serde_json::json!({"seconds": t.elapsed().as_secs_f64(), "patches": m.patch_count(), "memory_bytes": m.memory_bytes(), "stored": stored});
            }
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        ObjectsCommand::Delete { id } => {
            store.delete(&id)?;
            println!("deleted {id:?} from {}", store.url());
        }
        ObjectsCommand::Upgrade { ids, rows_per_view } => upgrade(store.as_ref(), ids, rows_per_view)?,
        ObjectsCommand::Copy { to, ids, replace } => copy(store.as_ref(), &to, ids, replace)?,
    }
    Ok(())
}

fn copy(from: &dyn crate::store::ObjectStore, to: &str, ids: Vec<String>, replace: bool) -> Result<()> {
    let target = crate::store::open(to)?;
    if target.url() == from.url() {
        anyhow::bail!("--to names the store the objects come from ({to})");
    }
    let ids = if ids.is_empty() { from.list()?.into_iter().map(|o| o.id).collect() } else { ids };
    let (mut copied, mut skipped) = (0, 0);
    for id in ids {
        if !replace && target.exists(&id)? {
            println!("{id}: already in {}, left alone (--replace overwrites)", target.url());
            skipped += 1;
            continue;
        }
        let t = Instant::now();
        let info = target.put(&from.get(&id)?, replace)?;
        println!("{id}: {:.1} MB in {:.2} s", info.bytes as f64 / 1e6, t.elapsed().as_secs_f64());
        copied += 1;
    }
    println!("copied {copied} object(s) from {} to {}; {skipped} left alone", from.url(), target.url());
    Ok(())
}

fn upgrade(store: &dyn crate::store::ObjectStore, ids: Vec<String>, rows_per_view: bool) -> Result<()> {
    let ids = if ids.is_empty() { store.list()?.into_iter().map(|o| o.id).collect() } else { ids };
    let renderer = super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?;
    for id in ids {
        let mut m = store.get(&id)?;
        let share_rows = rows_per_view && !m.rows_per_view();
        let lacked: Vec<&str> = [
            ("contour model", m.contours.get().is_none()),
            ("plain print runs", m.contour_lacks_plain_runs()),
            ("detector templates", m.detector.get().is_none()),
            ("symmetries", m.symmetries.is_none()),
            ("compact patch points", !m.patch_points.is_grid()),
            ("patch rows per view", share_rows),
        ]
        .iter()
        .filter(|(_, missing)| *missing)
        .map(|(what, _)| *what)
        .collect();
        let hint = if !rows_per_view && !m.rows_per_view() { " (patch rows per template: --rows-per-view keeps them once per view, smaller)" } else { "" };
        if lacked.is_empty() {
            println!("{id}: up to date{hint}");
            continue;
        }
        let t = Instant::now();
        let before = store.info(&id)?.bytes;
        m.add_what_older_versions_lacked(&renderer)?;
        m.contour_model_or_build(&renderer)?;
        m.shape_model_or_build(&renderer)?;
        if share_rows {
            crate::onboard::share_rows_per_view(&mut m).map_err(anyhow::Error::msg)?;
        }
        let after = store.put(&m, true)?.bytes;
        println!("{id}: added {} in {:.1} s, {:.1} → {:.1} MB{hint}", lacked.join(" and "), t.elapsed().as_secs_f64(), before as f64 / 1e6, after as f64 / 1e6);
    }
    Ok(())
}
