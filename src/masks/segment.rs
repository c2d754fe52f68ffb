//! Box → mask: GrabCut-style iterative graph-cut segmentation (Rother, Kolmogorov, Blake
//! 2004). Colour mixtures of the object (inside the box) and the background (a ring
//! around it, clipped to the image), a contrast-sensitive 8-connected smoothness term,
//! a minimum cut, the mixtures re-fitted to the new labels, a few times. Everything
//! outside the box is background. The box's surroundings are downsampled so the box's
//! long side is at most `max_side` cells, which bounds the time whatever the box size.

use super::components::components;
use super::gmm::{Colour, Gmm};
use super::maxflow::Graph;
use super::outline_matte::settle_outline;
use super::pixel_box::PixelBox;
use super::OBJECT;
use image::imageops::{self, FilterType};
use image::{GrayImage, Luma, RgbImage};
use std::time::Instant;

#[derive(Clone, Debug, PartialEq)]
pub struct SegmentConfig {
    /// The box's long side in working cells (larger boxes are downsampled).
    pub max_side: u32,
    /// Width of the background ring around the box, as a share of the box's long side.
    pub ring: f64,
    /// ... and at least this many image pixels.
    pub min_ring_px: u32,
    /// Gaussians per colour mixture.
    pub components: usize,
    /// Graph cuts, each followed by re-fitting the mixtures.
    pub iterations: usize,
    /// GrabCut's γ: the weight of a label change between two equal colours.
    pub smoothness: f64,
    /// Below this share of the box the cut has collapsed onto nothing ...
    pub min_fill: f64,
    /// ... above it, onto the whole box: both fall back to the inscribed ellipse.
    pub max_fill: f64,
    /// Relabel the cut's outline pixels by how much of each the object covers
    /// (`outline_matte`): the cut alone leaves the outline up to a pixel outside.
    pub settle_outline: bool,
}

impl Default for SegmentConfig {
    fn default() -> Self {
        Self { max_side: 160, ring: 0.2, min_ring_px: 4, components: 5, iterations: 4, smoothness: 50.0, min_fill: 0.05, max_fill: 0.98, settle_outline: true }
    }
}

/// How a box's mask was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    GraphCut,
    /// The segmentation failed or collapsed; the ellipse inscribed in the box is still a
    /// better outline than the box.
    EllipseFallback,
    /// The filled box, asked for explicitly.
    Fill,
}

#[derive(Clone, Debug)]
pub struct Segmentation {
    /// Image-sized, 255 = object.
    pub mask: GrayImage,
    pub method: Method,
    /// Share of the box's pixels in the mask.
    pub fill: f64,
    pub ms: f64,
    /// Why the fallback was taken.
    pub note: Option<String>,
}

/// Integer capacities for the max-flow: costs are in nats, ×64 keeps ~0.02 resolution.
const COST_SCALE: f64 = 64.0;
/// A colour no model has seen would cost ~∞; past this it no longer matters which.
const MAX_DATA_COST: f64 = 100.0;
/// Fewer cells than this inside the box (or in the ring) cannot fit a colour model.
const MIN_CELLS: usize = 16;

/// Segments the object inside `b` (already clipped to `image`).
pub fn segment_box(image: &RgbImage, b: &PixelBox, cfg: &SegmentConfig) -> Segmentation {
    let t = Instant::now();
    let grid = Grid::new(image, b, cfg);
    let outcome = grid.graph_cut(cfg).map(|labels| {
        let mut mask = grid.upsample(&clean(&grid, labels), b, image.width(), image.height());
        if cfg.settle_outline {
            settle_outline(image, &mut mask, b);
        }
        mask
    });
    let area = b.area() as f64;
    let share = |m: &GrayImage| m.as_raw().iter().filter(|&&v| v == OBJECT).count() as f64 / area;
    let checked = outcome.and_then(|mask| {
        let fill = share(&mask);
        if fill < cfg.min_fill || fill > cfg.max_fill {
            Err(format!("the cut kept {:.0} % of the box, outside {:.0}–{:.0} %", fill * 100.0, cfg.min_fill * 100.0, cfg.max_fill * 100.0))
        } else {
            Ok((mask, fill))
        }
    });
    let (mask, method, note) = match checked {
        Ok((mask, _)) => (mask, Method::GraphCut, None),
        Err(why) => (ellipse_in_box(image.width(), image.height(), b), Method::EllipseFallback, Some(format!("box segmentation fell back to the inscribed ellipse: {why}"))),
    };
    let fill = share(&mask);
    Segmentation { mask, method, fill, ms: t.elapsed().as_secs_f64() * 1e3, note }
}

/// The ellipse inscribed in the box (pixel centres at half-integers of the box's
/// continuous extent); never empty, since the centre pixel is always inside.
pub fn ellipse_in_box(width: u32, height: u32, b: &PixelBox) -> GrayImage {
    let (cx, cy) = ((b.x0 + b.x1) as f64 / 2.0, (b.y0 + b.y1) as f64 / 2.0);
    let (rx, ry) = (b.width() as f64 / 2.0, b.height() as f64 / 2.0);
    GrayImage::from_fn(width, height, |x, y| {
        let (u, v) = ((x as f64 + 0.5 - cx) / rx, (y as f64 + 0.5 - cy) / ry);
        Luma([if b.contains(x, y) && u * u + v * v <= 1.0 { OBJECT } else { 0 }])
    })
}

/// The box and its ring, downsampled: the graph's cells.
struct Grid {
    w: usize,
    h: usize,
    colour: Vec<Colour>,
    in_box: Vec<bool>,
    /// Image pixel of the grid's corner and cells per image pixel.
    origin: (u32, u32),
    scale: (f64, f64),
}

impl Grid {
    fn new(image: &RgbImage, b: &PixelBox, cfg: &SegmentConfig) -> Grid {
        let long = b.width().max(b.height());
        let ring = ((cfg.ring * long as f64).round() as u32).max(cfg.min_ring_px);
        let (rx0, ry0) = (b.x0.saturating_sub(ring), b.y0.saturating_sub(ring));
        let (rx1, ry1) = ((b.x1 + ring).min(image.width()), (b.y1 + ring).min(image.height()));
        let (rw, rh) = (rx1 - rx0, ry1 - ry0);
        let shrink = (cfg.max_side as f64 / long as f64).min(1.0);
        let (gw, gh) = (((rw as f64 * shrink).round() as u32).max(1), ((rh as f64 * shrink).round() as u32).max(1));
        let crop = imageops::crop_imm(image, rx0, ry0, rw, rh).to_image();
        let small = if (gw, gh) == (rw, rh) { crop } else { imageops::resize(&crop, gw, gh, FilterType::Triangle) };
        let scale = (gw as f64 / rw as f64, gh as f64 / rh as f64);
        let colour = small.pixels().map(|p| p.0.map(f64::from)).collect();
        let in_box = (0..gh)
            .flat_map(|j| (0..gw).map(move |i| (i, j)))
            .map(|(i, j)| {
                let (x, y) = (rx0 as f64 + (i as f64 + 0.5) / scale.0, ry0 as f64 + (j as f64 + 0.5) / scale.1);
                (b.x0 as f64..b.x1 as f64).contains(&x) && (b.y0 as f64..b.y1 as f64).contains(&y)
            })
            .collect();
        Grid { w: gw as usize, h: gh as usize, colour, in_box, origin: (rx0, ry0), scale }
    }

    /// Each unordered 8-neighbour pair once, as (cell, cell, distance between centres).
    fn neighbour_pairs(&self) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
        const STEPS: [(isize, isize); 4] = [(1, 0), (0, 1), (1, 1), (-1, 1)];
        (0..self.h).flat_map(move |y| {
            (0..self.w).flat_map(move |x| {
                STEPS.iter().filter_map(move |&(dx, dy)| {
                    let (nx, ny) = (x as isize + dx, y as isize + dy);
                    (nx >= 0 && nx < self.w as isize && ny < self.h as isize)
                        .then(|| (y * self.w + x, ny as usize * self.w + nx as usize, if dx != 0 && dy != 0 { std::f64::consts::SQRT_2 } else { 1.0 }))
                })
            })
        })
    }

    /// The pairs with a cell in the box (the ring is background whatever the cut), with
    /// their contrast-sensitive weight γ/dist · exp(−β‖Δz‖²), β = 1 / (2⟨‖Δz‖²⟩) over the
    /// whole grid.
    fn pairs(&self, gamma: f64) -> Vec<(usize, usize, f64)> {
        let d2 = |p: usize, q: usize| (0..3).map(|c| (self.colour[p][c] - self.colour[q][c]).powi(2)).sum::<f64>();
        let (sum, count) = self.neighbour_pairs().fold((0.0, 0usize), |(s, n), (p, q, _)| (s + d2(p, q), n + 1));
        let mean = sum / count.max(1) as f64;
        let beta = if mean > 0.0 { 0.5 / mean } else { 0.0 };
        self.neighbour_pairs().filter(|&(p, q, _)| self.in_box[p] || self.in_box[q]).map(|(p, q, dist)| (p, q, gamma / dist * (-beta * d2(p, q)).exp())).collect()
    }

    /// Object labels per cell after the iterated cuts; an error says why there is no cut.
    fn graph_cut(&self, cfg: &SegmentConfig) -> Result<Vec<bool>, String> {
        let inside = self.in_box.iter().filter(|&&b| b).count();
        let ring = self.in_box.len() - inside;
        if inside < MIN_CELLS {
            return Err(format!("the box is too small to segment ({inside} cells)"));
        }
        if ring < MIN_CELLS {
            return Err("no background around the box to learn its colours from".into());
        }
        let colours = |keep: &dyn Fn(usize) -> bool| (0..self.colour.len()).filter(|&i| keep(i)).map(|i| self.colour[i]).collect::<Vec<_>>();
        let no_model = || "too few distinct colours to model".to_string();
        let mut fg = Gmm::fit(&colours(&|i| self.in_box[i]), cfg.components).ok_or_else(no_model)?;
        let mut bg = Gmm::fit(&colours(&|i| !self.in_box[i]), cfg.components).ok_or_else(no_model)?;
        let pairs = self.pairs(cfg.smoothness);
        let node: Vec<Option<usize>> = self
            .in_box
            .iter()
            .scan(0, |n, &b| {
                Some(b.then(|| {
                    *n += 1;
                    *n - 1
                }))
            })
            .collect();
        let cells: Vec<usize> = (0..self.in_box.len()).filter(|&i| self.in_box[i]).collect();
        let cap = |cost: f64| (cost.min(MAX_DATA_COST) * COST_SCALE).round() as i64;
        // The smoothness terms do not change between rounds: the graph is built once, and
        // each round changes only the data terms on the flow the last one left.
        let mut g = Graph::new(inside);
        // Next to a ring cell, which is background: being object costs the pair.
        let mut ring_cost = vec![0i64; inside];
        for &(p, q, w) in &pairs {
            match (node[p], node[q]) {
                (Some(a), Some(b)) => g.add_edge(a, b, cap(w), cap(w)),
                (Some(a), None) | (None, Some(a)) => ring_cost[a] += cap(w),
                (None, None) => {}
            }
        }
        let mut labels = self.in_box.clone();
        for _ in 0..cfg.iterations {
            for &c in &cells {
                // Cutting s→v labels v background; cutting v→t labels it object.
                let (bg_cost, fg_cost) = (bg.neg_log_likelihood(&self.colour[c]), fg.neg_log_likelihood(&self.colour[c]));
                let base = bg_cost.min(fg_cost);
                let v = node[c].unwrap_or_default();
                g.set_terminal(v, cap(bg_cost - base), cap(fg_cost - base) + ring_cost[v]);
            }
            g.max_flow();
            let next: Vec<bool> = node.iter().map(|n| n.is_some_and(|v| g.is_source_side(v))).collect();
            let settled = next == labels;
            labels = next;
            if settled || !labels.iter().any(|&l| l) {
                break;
            }
            fg = fg.refit(&colours(&|i| labels[i])).unwrap_or(fg);
            bg = bg.refit(&colours(&|i| !labels[i])).unwrap_or(bg);
        }
        Ok(labels)
    }

    /// Image-sized mask: the cell labels bilinearly interpolated at each box pixel's
    /// centre, so an upsampled outline is not staircased by the cell size.
    fn upsample(&self, labels: &[bool], b: &PixelBox, width: u32, height: u32) -> GrayImage {
        let at = |i: isize, j: isize| {
            let (i, j) = (i.clamp(0, self.w as isize - 1) as usize, j.clamp(0, self.h as isize - 1) as usize);
            labels[j * self.w + i] as u8 as f64
        };
        GrayImage::from_fn(width, height, |x, y| {
            if !b.contains(x, y) {
                return Luma([0]);
            }
            let gx = (x as f64 + 0.5 - self.origin.0 as f64) * self.scale.0 - 0.5;
            let gy = (y as f64 + 0.5 - self.origin.1 as f64) * self.scale.1 - 0.5;
            let (i, j) = (gx.floor() as isize, gy.floor() as isize);
            let (fx, fy) = (gx - i as f64, gy - j as f64);
            let v = (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j)) + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1));
            Luma([if v >= 0.5 { OBJECT } else { 0 }])
        })
    }
}

/// A detection is one object: keep the largest 4-connected object region, and fill the
/// background regions it encloses (those touching neither the ring nor the grid's edge).
fn clean(grid: &Grid, labels: Vec<bool>) -> Vec<bool> {
    let (objects, sizes) = components(grid.w, grid.h, |i| labels[i]);
    let Some(largest) = (0..sizes.len()).max_by_key(|&c| sizes[c]) else { return labels };
    let (backgrounds, count) = components(grid.w, grid.h, |i| objects[i] != Some(largest));
    let mut open = vec![false; count.len()];
    for (i, background) in backgrounds.iter().enumerate() {
        let (x, y) = (i % grid.w, i / grid.w);
        let on_edge = x == 0 || y == 0 || x + 1 == grid.w || y + 1 == grid.h;
        if let Some(c) = background.filter(|_| on_edge || !grid.in_box[i]) {
            open[c] = true;
        }
    }
    (0..labels.len()).map(|i| backgrounds[i].is_none_or(|c| !open[c])).collect()
}

#[cfg(test)]
mod tests;
