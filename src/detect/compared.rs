//! Every searched object's candidates in one frame, from screen to answer: the one loop of
//! `b2tf bop run` and the service's `Estimate` by object id. Each object's first candidate
//! groups are screened (`Estimator::screen_scores`, through the caller's `screen`), those
//! another object's outrank on their place dropped (`rivals`), and the rest estimated in
//! turn until enough are sure (`confirm::estimate_instances`); with the depth detector's
//! candidates (`compared`), a place another object's answer surely took is not estimated
//! again (`confirm::on_taken_place`).
//!
//! The screens of all objects run side by side. So do the estimates of objects whose
//! candidates share no place: only an object sharing a place with an earlier one waits for
//! its answers (the taken places), so the answers are the same on any number of threads.

use super::confirm::{compared_at_most, compared_choice, estimate_instances, on_taken_place, same_place, sure_places, Choice, Instances};
use super::rivals::{boxes_meet, drop_outranked, Screened};
use crate::features::mask_bbox;
use image::GrayImage;

/// One object's candidates in the frame.
pub struct ObjectCandidates {
    /// Its candidate groups (indices into its detections, each group one instance's masks),
    /// best first.
    pub groups: Vec<Vec<usize>>,
    /// Instances of it wanted.
    pub wanted: usize,
    /// Whether its groups are screened (only its first `compared_at_most` then), or all
    /// estimated unscreened.
    pub screened: bool,
}

/// How the frame's candidates are chosen and how many threads work on them.
#[derive(Clone, Copy, Debug)]
pub struct Comparison {
    /// The depth detector's candidates: compared across objects (`compared_choice`) and
    /// kept off taken places.
    pub compared: bool,
    pub choice: Choice,
    pub threads: usize,
}

/// Screens, compares and estimates `objects`' candidates; returns each object's
/// `Instances`. `place(o, d)` is object o's detection d's mask (where an answer from it
/// lies); `screen(o, group)` a group's screen scores (`Ok(None)`: refused, dropped; only
/// called for screened objects); `estimate(o, instance, candidate)` an answer and its
/// confirmation (as `estimate_instances` takes it); `answer_place` the mask an answer was
/// estimated from, for the taken places.
pub fn answer_objects<'p, T: Send, E: Send>(
    objects: &[ObjectCandidates],
    how: Comparison,
    place: impl Fn(usize, usize) -> &'p GrayImage + Sync,
    screen: impl Fn(usize, &[usize]) -> Result<Option<Vec<f32>>, E> + Sync,
    estimate: impl Fn(usize, usize, &Screened) -> Result<(T, Option<f32>), E> + Sync,
    answer_place: fn(&T) -> Option<&GrayImage>,
) -> Result<Vec<Instances<T>>, E> {
    let started = std::time::Instant::now();
    let mut candidates = screened(objects, how.threads, &screen)?;
    drop_outranked(&mut candidates, |o, g| place(o, g[0]));
    let chains = if how.compared { sharing_places(&candidates, &place) } else { (0..objects.len()).map(|o| vec![o]).collect() };
    tracing::debug!(screen_s = started.elapsed().as_secs_f64(), ?chains, "candidates screened");
    // One chain's objects in order, each kept off the places the earlier ones surely took.
    let answer_chain = |chain: Vec<usize>| -> Result<Vec<(usize, Instances<T>)>, E> {
        let mut taken: Vec<GrayImage> = Vec::new();
        let mut answered = Vec::with_capacity(chain.len());
        for o in chain {
            let mut jobs: Vec<(usize, &Screened)> = candidates[o].iter().enumerate().collect();
            if how.compared {
                jobs.retain(|(_, c)| !on_taken_place(place(o, c.group[0]), &taken));
            }
            let wanted = objects[o].wanted;
            let choice = compared_choice(how.compared, jobs.len(), wanted, how.choice);
            let instances = estimate_instances(jobs, wanted, choice, |(instance, c)| estimate(o, instance, c))?;
            taken.extend(sure_places(instances.kept.iter().filter_map(|(t, c)| Some(((*c)?, answer_place(t)?)))));
            answered.push((o, instances));
        }
        Ok(answered)
    };
    let mut out: Vec<Option<Instances<T>>> = objects.iter().map(|_| None).collect();
    for (o, instances) in crate::parallel::ordered_map(chains, how.threads, answer_chain)?.into_iter().flatten() {
        out[o] = Some(instances);
    }
    Ok(out.into_iter().map(|i| i.unwrap_or(Instances { kept: Vec::new(), tried: 0, best: None })).collect())
}

/// Every object's chosen answers (`one_per_place`'s) passed through `review(object,
/// answer)`, side by side on `threads`, each kept in its object's list and order with its
/// score: with depth, the answers looked at again beside the depth's own views
/// (`Estimator::reviewed_in_depth`), which object each place holds being settled.
pub fn reviewed<T: Send, E: Send>(per_object: Vec<Vec<(T, f32)>>, threads: usize, review: impl Fn(usize, T) -> Result<T, E> + Sync) -> Result<Vec<Vec<(T, f32)>>, E> {
    let mut out: Vec<Vec<(T, f32)>> = per_object.iter().map(|_| Vec::new()).collect();
    let jobs: Vec<(usize, T, f32)> = per_object.into_iter().enumerate().flat_map(|(o, answers)| answers.into_iter().map(move |(t, s)| (o, t, s))).collect();
    let done = crate::parallel::ordered_map(jobs, threads, |(o, t, s)| Ok((o, review(o, t)?, s)))?;
    for (o, t, s) in done {
        out[o].push((t, s));
    }
    Ok(out)
}

/// Each object's groups that are estimated, with their screen scores where screened (all
/// objects' screens side by side); a group the screen refuses is dropped.
fn screened<E: Send>(objects: &[ObjectCandidates], threads: usize, screen: &(impl Fn(usize, &[usize]) -> Result<Option<Vec<f32>>, E> + Sync)) -> Result<Vec<Vec<Screened>>, E> {
    let jobs: Vec<(usize, &Vec<usize>)> = objects
        .iter()
        .enumerate()
        .flat_map(|(o, c)| {
            let at_most = if c.screened { compared_at_most(c.wanted) } else { usize::MAX };
            c.groups.iter().take(at_most).map(move |g| (o, g))
        })
        .collect();
    let owners: Vec<usize> = jobs.iter().map(|j| j.0).collect();
    let scored = crate::parallel::ordered_map(jobs, threads, |(o, group)| {
        let scores = if objects[o].screened { screen(o, group)?.map(Some) } else { Some(None) };
        Ok(scores.map(|scores| Screened { group: group.clone(), scores }))
    })?;
    let mut candidates: Vec<Vec<Screened>> = objects.iter().map(|_| Vec::new()).collect();
    for (o, s) in owners.into_iter().zip(scored) {
        candidates[o].extend(s);
    }
    Ok(candidates)
}

/// The objects in chains that must be estimated in turn, in object order within each: two
/// objects are in one chain when a detection of one's candidates lies on the place of one
/// of the other's (`same_place`), since an answer of the first would keep the second off
/// it. Chains come out by their first object.
fn sharing_places<'p>(candidates: &[Vec<Screened>], place: &impl Fn(usize, usize) -> &'p GrayImage) -> Vec<Vec<usize>> {
    // Every detection an object may be answered from, and the places its candidates are
    // checked at (each group's first), with their boxes.
    let boxed = |m: &'p GrayImage| (m, mask_bbox(m));
    let answered_from: Vec<Vec<_>> = candidates.iter().enumerate().map(|(o, cs)| cs.iter().flat_map(|c| c.group.iter().map(move |&d| boxed(place(o, d)))).collect()).collect();
    let checked_at: Vec<Vec<_>> = candidates.iter().enumerate().map(|(o, cs)| cs.iter().map(|c| boxed(place(o, c.group[0]))).collect()).collect();
    let mut chain_of: Vec<usize> = (0..candidates.len()).collect();
    let root = |chain_of: &Vec<usize>, mut o: usize| {
        while chain_of[o] != o {
            o = chain_of[o];
        }
        o
    };
    for (a, from) in answered_from.iter().enumerate() {
        for (b, at) in checked_at.iter().enumerate() {
            let shares = a != b && from.iter().any(|x| at.iter().any(|y| boxes_meet(x.1, y.1) && same_place(x.0, y.0)));
            if shares {
                let (ra, rb) = (root(&chain_of, a), root(&chain_of, b));
                chain_of[ra.max(rb)] = ra.min(rb);
            }
        }
    }
    let mut chains: Vec<Vec<usize>> = Vec::new();
    let mut chain_at: Vec<Option<usize>> = vec![None; candidates.len()];
    for o in 0..candidates.len() {
        let r = root(&chain_of, o);
        match chain_at[r] {
            Some(i) => chains[i].push(o),
            None => {
                chain_at[r] = Some(chains.len());
                chains.push(vec![o]);
            }
        }
    }
    chains
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    fn square(x0: u32) -> GrayImage {
        GrayImage::from_fn(96, 32, |x, y| image::Luma([u8::from(x >= x0 && x < x0 + 20 && y < 20)]))
    }

    #[test]
    fn objects_sharing_a_place_are_chained_and_the_others_stand_alone() {
        // Detections at x = 0, 2 (one place), 40 and 70.
        let places = [square(0), square(2), square(40), square(70)];
        let c = |d: usize| Screened { group: vec![d], scores: None };
        // Object 0 at place 0; object 1 at 40; object 2 at 2 (object 0's place) and 70;
        // object 3 at 70 (object 2's).
        let candidates = vec![vec![c(0)], vec![c(2)], vec![c(1), c(3)], vec![c(3)]];
        assert_eq!(sharing_places(&candidates, &|_, d| &places[d]), [vec![0, 2, 3], vec![1]]);
        // Nothing shared: every object alone.
        let apart = vec![vec![c(0)], vec![c(2)], vec![c(3)]];
        assert_eq!(sharing_places(&apart, &|_, d| &places[d]), [vec![0], vec![1], vec![2]]);
    }

    #[test]
    fn answers_are_the_same_on_any_number_of_threads() {
        // Object 0 at place 0 (sure), object 1 at place 1 (the same place, so taken: not
        // estimated) then at 40, object 2 at 70 (alone), object 3 screened out by a rival.
        let places = [square(0), square(2), square(40), square(70)];
        let objects = [
            ObjectCandidates { groups: vec![vec![0]], wanted: 1, screened: true },
            ObjectCandidates { groups: vec![vec![1], vec![2]], wanted: 1, screened: true },
            ObjectCandidates { groups: vec![vec![3]], wanted: 1, screened: false },
            ObjectCandidates { groups: vec![vec![0]], wanted: 1, screened: true },
        ];
        let score = |o: usize| [0.9, 0.8, 0.0, 0.1][o];
        let confirmation = |o: usize, d: usize| match (o, d) {
            (0, _) => 0.9,
            (1, 2) => 0.6,
            _ => 0.75,
        };
        for threads in [1, 2, 4] {
            let estimated = Mutex::new(Vec::new());
            let how = Comparison { compared: true, choice: Choice::Confirmed { min_score: 0.45 }, threads };
            let out = answer_objects(
                &objects,
                how,
                |_, d| &places[d],
                |o, _| Ok::<_, ()>(Some(vec![score(o)])),
                |o, _, c| {
                    estimated.lock().unwrap().push((o, c.group[0]));
                    Ok(((o, places[c.group[0]].clone()), Some(confirmation(o, c.group[0]))))
                },
                |t| Some(&t.1),
            )
            .unwrap();
            let mut estimated = estimated.into_inner().unwrap();
            estimated.sort();
            assert_eq!(estimated, [(0, 0), (1, 2), (2, 3)], "{threads} threads");
            let kept: Vec<Vec<usize>> = out.iter().map(|i| i.kept.iter().map(|k| k.0 .0).collect()).collect();
            assert_eq!(kept, [vec![0], vec![1], vec![2], vec![]], "{threads} threads");
            assert_eq!(out.iter().map(|i| i.tried).collect::<Vec<_>>(), [1, 1, 1, 0]);
        }
    }

    #[test]
    fn reviewed_answers_keep_their_object_order_and_score() {
        let answers = vec![vec![(1, 0.9), (2, 0.7)], vec![], vec![(3, 0.5)]];
        for threads in [1, 3] {
            let out = reviewed(answers.clone(), threads, |o, t| Ok::<_, ()>(t * 10 + o as i32)).unwrap();
            assert_eq!(out, [vec![(10, 0.9), (20, 0.7)], vec![], vec![(32, 0.5)]]);
        }
        assert_eq!(reviewed(answers, 2, |_, t| if t == 2 { Err("failed") } else { Ok(t) }), Err("failed"));
    }

    #[test]
    fn a_refused_screen_drops_its_group_and_an_error_stops_the_frame() {
        let places = [square(0), square(40)];
        let objects = [ObjectCandidates { groups: vec![vec![0], vec![1]], wanted: 1, screened: true }];
        let how = Comparison { compared: true, choice: Choice::Confirmed { min_score: 0.45 }, threads: 2 };
        let out = answer_objects(&objects, how, |_, d| &places[d], |_, g| Ok::<_, ()>((g[0] == 1).then(|| vec![0.5])), |_, _, c| Ok((c.group[0], Some(0.2))), |_| None).unwrap();
        assert_eq!(out[0].tried, 1, "only the group the screen took");
        let failed = answer_objects(&objects, how, |_, d| &places[d], |_, _| Err("refused"), |_, _, c| Ok((c.group[0], Some(0.2))), |_| None);
        assert_eq!(failed.err(), Some("refused"));
    }
}
