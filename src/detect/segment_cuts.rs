//! Other readings of the frame's surfaces than the one its depth jumps give
//! (`depth_segments`). On real sensors things that touch are often one surface (no jump
//! where a box leans on a mug, or a few noisy pixels bridging two things on a desk), and
//! one thing is often two (a mug's inside and outside, split at its rim). So a surface
//! larger than any object looked for is also offered cut at its depths (`split_by_depth`)
//! and at its necks (`split_at_necks`), and neighbouring surfaces also joined in pairs
//! (`neighbouring_pairs`). The segmentation keeps every reading; the estimate's confirmation
//! at its pose chooses among them.

use crate::depth::surfaces::surfaces;
use crate::depth::DepthImage;
use std::collections::{HashMap, VecDeque};

/// Segments and parts smaller than this (pixels) are noise at depth edges.
pub(super) const MIN_PIXELS: usize = 120;
/// A bridge at most twice this wide (pixels) between two parts of a surface is a neck:
/// what sensor noise and flying pixels leave between things standing close together.
const NECK_PX: usize = 2;
/// Two surfaces are neighbours when this many of their pixels lie within `CONTACT_PX`
/// of the other: touching along an edge, not at a corner or through one stray pixel.
const MIN_CONTACT: usize = 12;
const CONTACT_PX: usize = 2;

/// The `cells` (row-major indices, kept in their order) of each surface `label`, by label.
pub(super) fn group_by_surface(label: &[Option<usize>], cells: impl IntoIterator<Item = usize>) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = vec![Vec::new(); label.iter().flatten().max().map_or(0, |m| m + 1)];
    for i in cells {
        if let Some(l) = label[i] {
            groups[l].push(i);
        }
    }
    groups
}

/// A surface whose `pixels` lie at two depths, one thing in front of another (a box
/// leaning on a mug: no depth jump where they meet), cut at the depth that best separates
/// them (Otsu's threshold over their depths): each side's connected parts of `MIN_PIXELS`
/// or more (none when one side is too small).
pub(super) fn split_by_depth(depth: &DepthImage, pixels: &[usize]) -> Vec<Vec<usize>> {
    let (w, h) = (depth.width() as usize, depth.height() as usize);
    let z_of = |i: usize| depth.at((i % w) as u32, (i / w) as u32) as f64;
    let zs: Vec<f64> = pixels.iter().map(|&i| z_of(i)).filter(|&z| z > 0.0).collect();
    let Some(cut) = otsu_threshold(&zs) else { return Vec::new() };
    let mut parts = Vec::new();
    for near in [true, false] {
        let mut member = vec![false; w * h];
        for &i in pixels {
            let z = z_of(i);
            member[i] = z > 0.0 && (z <= cut) == near;
        }
        let label = surfaces(w, h, &member, &|x, y| depth.at(x as u32, y as u32) as f64);
        parts.extend(group_by_surface(&label, pixels.iter().copied()).into_iter().filter(|p| p.len() >= MIN_PIXELS));
    }
    parts
}

/// A surface of a `w × h` frame made of parts joined by thin bridges (two things side by
/// side at one distance, bridged by noisy pixels along the table): its pixels eroded by
/// `NECK_PX`, and when that leaves two or more cores of `MIN_PIXELS`, every pixel given to
/// the core nearest it within the surface. The parts; none when it holds no neck.
pub(super) fn split_at_necks(w: usize, h: usize, pixels: &[usize]) -> Vec<Vec<usize>> {
    let mut inside = vec![false; w * h];
    for &i in pixels {
        inside[i] = true;
    }
    let mut core = inside.clone();
    for _ in 0..NECK_PX {
        let before = core.clone();
        for &i in pixels {
            core[i] = before[i] && neighbours(w, h, i).iter().all(|n| n.is_some_and(|n| before[n]));
        }
    }
    let label = surfaces(w, h, &core, &|_, _| 0.0);
    let cores: Vec<Vec<usize>> = group_by_surface(&label, pixels.iter().copied()).into_iter().filter(|c| c.len() >= MIN_PIXELS).collect();
    if cores.len() < 2 {
        return Vec::new();
    }
    // Grown back breadth first within the surface: each pixel to the core that reaches it first.
    let mut owner: Vec<Option<usize>> = vec![None; w * h];
    let mut queue = VecDeque::new();
    for (c, cells) in cores.iter().enumerate() {
        for &i in cells {
            owner[i] = Some(c);
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        for n in neighbours(w, h, i).into_iter().flatten() {
            if inside[n] && owner[n].is_none() {
                owner[n] = owner[i];
                queue.push_back(n);
            }
        }
    }
    group_by_surface(&owner, pixels.iter().copied())
}

/// Pairs of `parts` (pixel lists of a `w × h` frame, sharing no pixel) that touch along an
/// edge: at least `MIN_CONTACT` pixels of one within `CONTACT_PX` of the other. The
/// caller offers each pair joined, as one thing seen as two surfaces.
pub(super) fn neighbouring_pairs(w: usize, h: usize, parts: &[&[usize]]) -> Vec<(usize, usize)> {
    let mut label: Vec<Option<usize>> = vec![None; w * h];
    for (p, cells) in parts.iter().enumerate() {
        for &i in cells.iter() {
            label[i] = Some(p);
        }
    }
    let r = CONTACT_PX as i64;
    let mut contacts: HashMap<(usize, usize), usize> = HashMap::new();
    let mut touched: Vec<usize> = Vec::new();
    for (p, cells) in parts.iter().enumerate() {
        for &i in cells.iter() {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            touched.clear();
            for dy in -r..=r {
                for dx in -r..=r {
                    let (xx, yy) = (x + dx, y + dy);
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    if let Some(q) = label[yy as usize * w + xx as usize] {
                        if q > p && !touched.contains(&q) {
                            touched.push(q);
                        }
                    }
                }
            }
            for &q in &touched {
                *contacts.entry((p, q)).or_default() += 1;
            }
        }
    }
    let mut pairs: Vec<(usize, usize)> = contacts.into_iter().filter(|&(_, n)| n >= MIN_CONTACT).map(|(pair, _)| pair).collect();
    pairs.sort_unstable();
    pairs
}

/// The 4-neighbours of cell `i` in a `w × h` grid (None past its edges).
fn neighbours(w: usize, h: usize, i: usize) -> [Option<usize>; 4] {
    let (x, y) = (i % w, i / w);
    [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)]
}

/// The value that splits `values` into two groups of the largest between-group variance
/// (Otsu, over 64 bins); None when they do not spread or one group would be empty.
fn otsu_threshold(values: &[f64]) -> Option<f64> {
    const BINS: usize = 64;
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if values.is_empty() || hi - lo <= 0.0 {
        return None;
    }
    let bin = |v: f64| (((v - lo) / (hi - lo) * BINS as f64) as usize).min(BINS - 1);
    let mut hist = [0usize; BINS];
    for &v in values {
        hist[bin(v)] += 1;
    }
    let (n, sum) = (values.len() as f64, hist.iter().enumerate().map(|(b, &c)| b as f64 * c as f64).sum::<f64>());
    let (mut below, mut below_sum, mut best) = (0.0, 0.0, None::<(f64, usize)>);
    for (b, &c) in hist.iter().enumerate().take(BINS - 1) {
        below += c as f64;
        below_sum += b as f64 * c as f64;
        let above = n - below;
        if below == 0.0 || above == 0.0 {
            continue;
        }
        let between = below * above * (below_sum / below - (sum - below_sum) / above).powi(2);
        if best.is_none_or(|(v, _)| between > v) {
            best = Some((between, b));
        }
    }
    best.map(|(_, b)| lo + (b + 1) as f64 * (hi - lo) / BINS as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(w: usize, x0: usize, x1: usize, y0: usize, y1: usize) -> Vec<usize> {
        (y0..y1).flat_map(|y| (x0..x1).map(move |x| y * w + x)).collect()
    }

    #[test]
    fn otsu_cuts_between_two_depth_groups() {
        let zs: Vec<f64> = (0..100).map(|i| if i < 60 { 0.50 + 0.0004 * i as f64 } else { 0.60 + 0.0004 * i as f64 }).collect();
        let cut = otsu_threshold(&zs).unwrap();
        assert!(cut > zs[59] && cut < zs[60], "{cut} between {} and {}", zs[59], zs[60]);
        assert_eq!(otsu_threshold(&[0.5; 10]), None);
        assert_eq!(otsu_threshold(&[]), None);
    }

    /// Two 30 × 30 squares joined by a bridge 2 px high: two parts, every pixel given to
    /// one, the bridge split between them; a solid rectangle has no neck.
    #[test]
    fn things_joined_by_a_thin_bridge_are_cut_apart_there() {
        let w = 100;
        let mut pixels = rect(w, 10, 40, 10, 40);
        pixels.extend(rect(w, 40, 50, 24, 26));
        pixels.extend(rect(w, 50, 80, 10, 40));
        let parts = split_at_necks(w, 60, &pixels);
        assert_eq!(parts.len(), 2, "{:?}", parts.iter().map(|p| p.len()).collect::<Vec<_>>());
        assert_eq!(parts.iter().map(|p| p.len()).sum::<usize>(), pixels.len());
        for p in &parts {
            let xs: Vec<usize> = p.iter().map(|i| i % w).collect();
            assert!(xs.iter().all(|&x| x < 46) || xs.iter().all(|&x| x >= 44), "one side each");
            assert!(p.len() >= 900 && p.len() <= 920);
        }
        assert!(split_at_necks(w, 60, &rect(w, 10, 80, 10, 40)).is_empty());
    }

    /// Parts touching along an edge are neighbours; a part 5 px away, or touching another
    /// at one corner only, is not.
    #[test]
    fn surfaces_touching_along_an_edge_are_neighbours() {
        let w = 100;
        let parts = [rect(w, 10, 30, 10, 30), rect(w, 31, 50, 10, 30), rect(w, 55, 70, 10, 30), rect(w, 71, 90, 31, 50)];
        assert_eq!(neighbouring_pairs(w, 60, &parts.iter().map(Vec::as_slice).collect::<Vec<_>>()), vec![(0, 1)]);
    }
}
