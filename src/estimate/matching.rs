//! Dense matching: for each query patch its k nearest pool patches (cosine, by blocked
//! matrix multiplication), then the mutual-nearest-neighbour filter.

use rayon::prelude::*;

/// A query patch matched to a pool patch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    pub query: usize,
    pub pool: usize,
    pub similarity: f32,
}

/// Pool columns per block: bounds the similarity buffer (queries × block floats).
const BLOCK: usize = 8192;

/// Pool columns per strip of the best-query scan: a strip's running maxima stay in cache
/// while the rows stream past.
const STRIP: usize = 512;

/// `query` is `q × dim`, `pool` is `p × dim`, both row-major and L2-normalised. Returns the
/// pairs (i, j) where j is among the `k_nn` most similar pool rows of query i and i is the
/// most similar query row of pool j.
pub fn mutual_matches(query: &[f32], pool: &[f32], dim: usize, k_nn: usize) -> Vec<Match> {
    let Some(Ranked { top, best_query }) = rank(query, pool, dim, k_nn) else { return vec![] };
    let mut out = Vec::new();
    for (i, t) in top.iter().enumerate() {
        for &(j, s) in t {
            // Orthogonal or opposite descriptors share nothing: never a match.
            if best_query[j] == i && s > 0.0 {
                out.push(Match { query: i, pool: j, similarity: s });
            }
        }
    }
    out
}

/// One part of a grouped match: query rows, the pool rows they may match, and for each
/// query row the patch it stands for (rows of different groups may stand for one patch).
pub struct MatchGroup<'a> {
    pub query: &'a [f32],
    pub patches: &'a [usize],
    pub pool: &'a [f32],
}

/// `mutual_matches` where the query is seen several ways (the photo turned for each turn of
/// the templates, `estimate::turned`), each way against its own pool: a query row's pool
/// neighbours and a pool row's best query come from its own group, but the `k_nn` nearest
/// are counted per *patch* across the groups, so a patch keeps its best matches over all
/// the turns as one pool of all templates would. Returns (group, match within the group).
pub fn grouped_mutual_matches(groups: &[MatchGroup<'_>], dim: usize, k_nn: usize) -> Vec<(usize, Match)> {
    // Groups side by side: a turn's group is small (its templates against its own query),
    // too small for `rank`'s own split across the cores to pay on its own.
    let ranked: Vec<Option<Ranked>> = groups.par_iter().map(|g| rank(g.query, g.pool, dim, k_nn)).collect();
    // Per patch: its best k (group, query row, pool row, similarity) over every group.
    let mut per_patch: std::collections::BTreeMap<usize, Vec<(usize, usize, usize, f32)>> = Default::default();
    for (g, r) in ranked.iter().enumerate() {
        let Some(r) = r else { continue };
        for (i, t) in r.top.iter().enumerate() {
            let best = per_patch.entry(groups[g].patches[i]).or_default();
            for &(j, s) in t {
                if best.len() < k_nn || s > best[best.len() - 1].3 {
                    let pos = best.partition_point(|&(.., v)| v >= s);
                    best.insert(pos, (g, i, j, s));
                    best.truncate(k_nn);
                }
            }
        }
    }
    let mut out = Vec::new();
    for best in per_patch.values() {
        for &(g, i, j, s) in best {
            let r = ranked[g].as_ref().expect("ranked above");
            if r.best_query[j] == i && s > 0.0 {
                out.push((g, Match { query: i, pool: j, similarity: s }));
            }
        }
    }
    out
}

/// Each query row's `k_nn` most similar pool rows (best first) and each pool row's most
/// similar query row; `None` when either side is empty.
struct Ranked {
    top: Vec<Vec<(usize, f32)>>,
    /// Per pool row, its most similar query (the first of equals).
    best_query: Vec<usize>,
}

/// Similarities a query's best-k scan checks at once against its k-th best before looking
/// at them one by one: once a query holds k, most of a block is below its k-th.
const SKIP_RUN: usize = 16;

fn rank(query: &[f32], pool: &[f32], dim: usize, k_nn: usize) -> Option<Ranked> {
    let q = query.len() / dim.max(1);
    let p = pool.len() / dim.max(1);
    if q == 0 || p == 0 || dim == 0 || k_nn == 0 {
        return None;
    }
    // Per query: its best k (pool index, similarity), sorted descending.
    let mut top: Vec<Vec<(usize, f32)>> = vec![Vec::with_capacity(k_nn + 1); q];
    // Per pool row: its best query and that similarity, in two arrays so that the scan
    // below compares and selects whole vectors of them.
    let (mut best_query, mut best_sim) = (vec![u32::MAX; p], vec![f32::NEG_INFINITY; p]);
    let mut sims = vec![0f32; q * BLOCK.min(p)];
    for start in (0..p).step_by(BLOCK) {
        let n = BLOCK.min(p - start);
        let block = &pool[start * dim..(start + n) * dim];
        let sims = &mut sims[..q * n];
        crate::linalg::mul_transposed(query, block, q, n, dim, sims);
        let sims = &*sims;
        // Two scans on all cores, each over its own outputs: rows for each query's best k,
        // column strips for each pool row's best query (rows in order, so ties go to the
        // first query as a single scan would).
        top.par_iter_mut().enumerate().for_each(|(i, t)| {
            for (run, values) in sims[i * n..(i + 1) * n].chunks(SKIP_RUN).enumerate() {
                // Nothing in the run beats the k-th best: none would be inserted below.
                if t.len() == k_nn && !values.iter().fold(false, |any, &s| any | (s > t[k_nn - 1].1)) {
                    continue;
                }
                for (j, &s) in values.iter().enumerate() {
                    if t.len() < k_nn || s > t[t.len() - 1].1 {
                        let pos = t.partition_point(|&(_, v)| v >= s);
                        t.insert(pos, (start + run * SKIP_RUN + j, s));
                        t.truncate(k_nn);
                    }
                }
            }
        });
        let strips = best_query[start..start + n].par_chunks_mut(STRIP).zip(best_sim[start..start + n].par_chunks_mut(STRIP));
        strips.enumerate().for_each(|(c, (index, best))| {
            let (j0, w) = (c * STRIP, best.len());
            for i in 0..q {
                for ((b, bi), &s) in best.iter_mut().zip(index.iter_mut()).zip(&sims[i * n + j0..i * n + j0 + w]) {
                    if s > *b {
                        *b = s;
                        *bi = i as u32;
                    }
                }
            }
        });
    }
    Some(Ranked { top, best_query: best_query.into_iter().map(|i| if i == u32::MAX { usize::MAX } else { i as usize }).collect() })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn normalized(rows: &[[f32; 3]]) -> Vec<f32> {
        rows.iter()
            .flat_map(|r| {
                let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
                r.map(|x| x / n)
            })
            .collect()
    }

    #[test]
    fn mutual_filter_keeps_only_reciprocal_pairs() {
        let query = normalized(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.9, 0.1, 0.0]]);
        let pool = normalized(&[[0.0, 1.0, 0.05], [1.0, 0.02, 0.0], [0.0, 0.0, 1.0]]);
        let m = mutual_matches(&query, &pool, 3, 1);
        let pairs: Vec<(usize, usize)> = m.iter().map(|m| (m.query, m.pool)).collect();
        // Query 2 also prefers pool 1, but pool 1's best query is query 0.
        assert_eq!(pairs, vec![(0, 1), (1, 0)]);
        // With k = 3, query 2's list holds pool 1 too, still not mutual.
        assert_eq!(mutual_matches(&query, &pool, 3, 3).len(), 2);
        assert!(mutual_matches(&[], &pool, 3, 3).is_empty());
    }

    /// The blocked, run-skipping scans give exactly the pairs of a plain reading of the
    /// definition: each query's k most similar pool rows (earlier rows first among equals),
    /// kept where the query is the pool row's most similar (the first of equals), with
    /// repeated descriptors so that ties occur.
    #[test]
    fn scans_match_the_definition() {
        let dim = 6;
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 33) % 1000) as f32 / 500.0 - 1.0
        };
        let rows = |n: usize, next: &mut dyn FnMut() -> f32| -> Vec<f32> {
            let mut v: Vec<f32> = (0..n * dim).map(|_| next()).collect();
            for r in v.chunks_mut(dim) {
                let norm = r.iter().map(|x| x * x).sum::<f32>().sqrt();
                r.iter_mut().for_each(|x| *x /= norm);
            }
            v
        };
        let query = rows(45, &mut next);
        let mut pool = rows(700, &mut next);
        pool.copy_within(0..dim * 20, dim * 300); // twenty pool rows twice
        for k_nn in [1, 3, 5] {
            let sim = |i: usize, j: usize| (0..dim).map(|d| query[i * dim + d] * pool[j * dim + d]).sum::<f32>();
            let mut expected = vec![];
            for i in 0..45 {
                let mut order: Vec<usize> = (0..700).collect();
                order.sort_by(|&a, &b| sim(i, b).total_cmp(&sim(i, a)));
                for &j in order.iter().take(k_nn) {
                    let best = (0..45).fold(0, |b, q| if sim(q, j) > sim(b, j) { q } else { b });
                    if best == i && sim(i, j) > 0.0 {
                        expected.push((i, j));
                    }
                }
            }
            let got: Vec<(usize, usize)> = mutual_matches(&query, &pool, dim, k_nn).iter().map(|m| (m.query, m.pool)).collect();
            assert_eq!(got, expected, "k = {k_nn}");
        }
    }

    /// One group whose rows stand for themselves is `mutual_matches`; across groups, a
    /// patch's nearest pool rows are counted over all its rows, so a better match in one
    /// group pushes out a worse one in another.
    #[test]
    fn grouped_matches_compete_per_patch_across_groups() {
        let query = normalized(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.9, 0.1, 0.0]]);
        let pool = normalized(&[[0.0, 1.0, 0.05], [1.0, 0.02, 0.0], [0.0, 0.0, 1.0]]);
        let one = [MatchGroup { query: &query, patches: &[0, 1, 2], pool: &pool }];
        let grouped: Vec<Match> = grouped_mutual_matches(&one, 3, 2)
            .into_iter()
            .map(|(g, m)| {
                assert_eq!(g, 0);
                m
            })
            .collect();
        assert_eq!(grouped, mutual_matches(&query, &pool, 3, 2));

        // Patch 0 seen two ways: at 0.9 to group 0's pool, exactly to group 1's.
        let (q0, p0) = (normalized(&[[1.0, 0.0, 0.0]]), normalized(&[[0.9, 0.44, 0.0]]));
        let (q1, p1) = (normalized(&[[0.0, 0.0, 1.0]]), normalized(&[[0.0, 0.0, 1.0]]));
        let both = [MatchGroup { query: &q0, patches: &[0], pool: &p0 }, MatchGroup { query: &q1, patches: &[0], pool: &p1 }];
        let m = grouped_mutual_matches(&both, 3, 1);
        assert_eq!(m.len(), 1);
        assert_eq!((m[0].0, m[0].1.query, m[0].1.pool), (1, 0, 0));
        assert_eq!(grouped_mutual_matches(&both, 3, 2).len(), 2, "with two neighbours each keeps its own");
        // Different patches do not compete.
        let apart = [MatchGroup { query: &q0, patches: &[0], pool: &p0 }, MatchGroup { query: &q1, patches: &[1], pool: &p1 }];
        assert_eq!(grouped_mutual_matches(&apart, 3, 1).len(), 2);
    }
}
