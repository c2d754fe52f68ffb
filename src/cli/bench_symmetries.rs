//! `b2tf bench symmetries`: what the symmetry finder makes of meshes, how long it takes, and,
//! given a BOP `models_info.json`, whether it agrees with the symmetries declared there.

use crate::geometry::symmetry::{parse_models_info, ObjectSymmetries};
use crate::mesh::{load_mesh, Units};
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchSymmetriesArgs {
    /// Mesh files (BOP names `obj_NNNNNN.ply` are matched with `--models-info`).
    #[arg(long, required = true, num_args = 1..)]
    pub mesh: Vec<PathBuf>,
    /// Length unit of PLY/OBJ files.
    #[arg(long)]
    pub units: Option<Units>,
    /// A BOP `models_info.json` whose declared symmetries the found ones are compared with.
    #[arg(long)]
    pub models_info: Option<PathBuf>,
}

pub fn run(a: BenchSymmetriesArgs) -> Result<()> {
    let declared = match &a.models_info {
        Some(p) => Some(parse_models_info(&std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?).with_context(|| p.display().to_string())?),
        None => None,
    };
    // The shape's own symmetries, colours ignored: the turns that only the texture tells apart.
    let geometry_only = crate::mesh::symmetry_finder::FinderConfig { max_colour_misses: 1.0, ..Default::default() };
    println!("| mesh | triangles | found | declared | agree | ms | shape alone (colours ignored) |");
    println!("|---|---:|---|---|---|---:|---|");
    let mut agreed = (0, 0);
    for path in &a.mesh {
        let mesh = load_mesh(path, a.units)?;
        let t = Instant::now();
        let found = crate::mesh::symmetry_finder::find_symmetries(&mesh, &Default::default());
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let id = bop_id(path);
        let given = declared.as_ref().zip(id).and_then(|(d, id)| d.get(&id));
        let agree = given.map(|g| same_kind(g, &found));
        if let Some(ok) = agree {
            agreed = (agreed.0 + ok as usize, agreed.1 + 1);
        }
        let shape = crate::mesh::symmetry_finder::find_symmetries(&mesh, &geometry_only);
        println!(
            "| {} | {} | {} | {} | {} | {ms:.0} | {} |",
            path.file_name().map(|n| n.to_string_lossy()).unwrap_or_default(),
            mesh.triangles().len(),
            found.describe(),
            given.map(ObjectSymmetries::describe).unwrap_or_else(|| "–".into()),
            agree.map(|ok| if ok { "yes" } else { "no" }).unwrap_or("–"),
            shape.describe(),
        );
    }
    if agreed.1 > 0 {
        println!("agree with models_info on {} of {} meshes (same number of continuous axes, same number of discrete symmetries)", agreed.0, agreed.1);
    }
    Ok(())
}

/// `obj_000012.ply` → 12.
fn bop_id(path: &std::path::Path) -> Option<u32> {
    path.file_stem()?.to_str()?.strip_prefix("obj_")?.parse().ok()
}

/// The same kind of symmetry: as many continuous axes and discrete symmetries. (The group
/// is what matters to a user; BOP's hand-written matrices and the found ones differ by
/// rounding and by the point the axes pass through.)
fn same_kind(a: &ObjectSymmetries, b: &ObjectSymmetries) -> bool {
    a.continuous.len() == b.continuous.len() && a.discrete.len() == b.discrete.len()
}
