//! One object's templates over one scale's response maps: every template at every grid
//! position (a sum of byte lookups per feature, vectorised over the grid), the best
//! template per position, local maxima above the threshold, each then placed to the pixel
//! and to the neighbouring in-plane turn.

use super::responses::ResponseMaps;
use super::templates::ShapeModel;
use rayon::prelude::*;

/// A template placed in a resampled image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub template: usize,
    /// Projected object centre in the resampled image's pixels.
    pub x: i32,
    pub y: i32,
    /// Score above chance (`specific_score_at`), −1–1.
    pub score: f32,
}

/// Score of template `t` with its centre at pixel (x, y), as a share of the maximum.
pub fn score_at(model: &ShapeModel, maps: &ResponseMaps, t: usize, x: i32, y: i32) -> f32 {
    let f = model.template(t);
    let sum: u32 = f.iter().map(|f| maps.at(x + f.dx as i32, y + f.dy as i32, f.orientation as u8) as u32).sum();
    sum as f32 / (4 * f.len()) as f32
}

/// What a lone edge of the feature's orientation scores above chance: 4 for the match,
/// minus the mean over orientations (4 + 1 + 1 of 8 bins).
const CLEAN_EDGE: f32 = 4.0 - 6.0 / 8.0;

/// The template's score above chance (−1–1): each feature's response minus the mean
/// response of all orientations where it lands. Clutter with edges of every orientation
/// answers any template; there this is near 0, while a lone edge of the right orientation
/// still counts fully.
pub fn specific_score_at(model: &ShapeModel, maps: &ResponseMaps, t: usize, x: i32, y: i32) -> f32 {
    let f = model.template(t);
    let sum: f32 = f
        .iter()
        .map(|f| {
            let (px, py) = (x + f.dx as i32, y + f.dy as i32);
            maps.at(px, py, f.orientation as u8) as f32 - maps.chance_at(px, py)
        })
        .sum();
    sum / (CLEAN_EDGE * f.len() as f32)
}

/// Best template and its raw score at every grid position.
fn best_per_position(model: &ShapeModel, maps: &ResponseMaps) -> (Vec<u8>, Vec<u16>) {
    let cells = maps.gw * maps.gh;
    let chunk = model.template_count().div_ceil(rayon::current_num_threads().max(1) * 4).max(1);
    let partial: Vec<(Vec<u8>, Vec<u16>)> = (0..model.template_count())
        .collect::<Vec<_>>()
        .par_chunks(chunk)
        .map(|ts| {
            let (mut best, mut which) = (vec![0u8; cells], vec![0u16; cells]);
            let mut acc = vec![0u8; cells];
            for &t in ts {
                acc.fill(0);
                for f in model.template(t) {
                    maps.accumulate(&mut acc, f.dx as i32, f.dy as i32, f.orientation as u8);
                }
                for ((b, w), &a) in best.iter_mut().zip(which.iter_mut()).zip(&acc) {
                    if a > *b {
                        *b = a;
                        *w = t as u16;
                    }
                }
            }
            (best, which)
        })
        .collect();
    let mut it = partial.into_iter();
    let (mut best, mut which) = it.next().unwrap_or_else(|| (vec![0; cells], vec![0; cells]));
    for (b2, w2) in it {
        for i in 0..cells {
            if b2[i] > best[i] {
                best[i] = b2[i];
                which[i] = w2[i];
            }
        }
    }
    (best, which)
}

/// Grid local maxima (3×3) whose raw score reaches `min_raw`, refined, then kept when
/// their score above chance reaches `min_score`.
pub fn search(model: &ShapeModel, maps: &ResponseMaps, min_raw: f32, min_score: f32) -> Vec<Placement> {
    if model.template_count() == 0 || maps.gw == 0 || maps.gh == 0 {
        return vec![];
    }
    let n = model.config.features;
    // The grid score can only rise when refined, but a little: take a margin below.
    let floor = (min_raw.max(0.0) * (4 * n) as f32).ceil() as u8;
    let (best, which) = best_per_position(model, maps);
    let (gw, gh) = (maps.gw as i32, maps.gh as i32);
    let mut out = Vec::new();
    for gy in 0..gh {
        for gx in 0..gw {
            let v = best[(gy * gw + gx) as usize];
            if v < floor.max(1) {
                continue;
            }
            let is_max = (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    let (x, y) = (gx + dx, gy + dy);
                    if (dx, dy) == (0, 0) || x < 0 || y < 0 || x >= gw || y >= gh {
                        return true;
                    }
                    let o = best[(y * gw + x) as usize];
                    // Ties go to the first in raster order.
                    o < v || (o == v && (dy, dx) > (0, 0))
                })
            });
            if !is_max {
                continue;
            }
            let t = which[(gy * gw + gx) as usize] as usize;
            let p = refine(model, maps, t, gx * maps.stride as i32, gy * maps.stride as i32);
            if p.score >= min_score {
                out.push(p);
            }
        }
    }
    out
}

/// The best pixel within the grid cell's window and the best of the template and its
/// in-plane neighbours there.
fn refine(model: &ShapeModel, maps: &ResponseMaps, t: usize, x: i32, y: i32) -> Placement {
    let steps = model.config.in_plane_steps as usize;
    let (view, turn) = (t / steps, t % steps);
    let turns = [turn, (turn + 1) % steps, (turn + steps - 1) % steps];
    let half = maps.stride as i32 / 2;
    let mut best = Placement { template: t, x, y, score: -1.0 };
    for &k in &turns {
        let tt = view * steps + k;
        for dy in -half..=half {
            for dx in -half..=half {
                let s = specific_score_at(model, maps, tt, x + dx, y + dy);
                if s > best.score {
                    best = Placement { template: tt, x: x + dx, y: y + dy, score: s };
                }
            }
        }
    }
    best
}
