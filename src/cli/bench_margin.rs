//! `bench estimate`'s margin table: how often the answer was right at each margin by which
//! its runner-up lost (`estimate::runner_up`), so that a caller knows what a margin means
//! before acting on it.

/// Upper ends of the margin bins (the last bin is open).
const BINS: [f64; 3] = [0.01, 0.03, 0.1];

/// Per bin (the margin's bins, then "no runner-up"): (right, answered).
#[derive(Default)]
pub struct MarginTally {
    bins: [(usize, usize); BINS.len() + 2],
}

impl MarginTally {
    /// One answered instance: its runner-up's margin (`None`: it had none) and whether the
    /// answer was right (MSSD < 0.1·d).
    pub fn push(&mut self, margin: Option<f64>, right: bool) {
        let bin = match margin {
            None => BINS.len() + 1,
            Some(m) => BINS.iter().position(|&b| m < b).unwrap_or(BINS.len()),
        };
        self.bins[bin].0 += right as usize;
        self.bins[bin].1 += 1;
    }

    pub fn report(&self) -> String {
        let mut names: Vec<String> = Vec::new();
        let mut lower = 0.0;
        for b in BINS {
            names.push(format!("{lower}–{b}"));
            lower = b;
        }
        names.push(format!("≥ {lower}"));
        names.push("no runner-up".into());
        let cells: Vec<String> = names.iter().zip(&self.bins).map(|(n, (right, all))| format!("{n}: {right}/{all}")).collect();
        format!("right answers by the runner-up's margin (with RRC): {}", cells.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn margins_fall_in_their_bins_and_none_in_its_own() {
        let mut t = MarginTally::default();
        t.push(Some(0.0), false);
        t.push(Some(0.02), true);
        t.push(Some(0.03), true); // a bin's upper end belongs to the next
        t.push(Some(0.5), true);
        t.push(None, true);
        t.push(None, false);
        assert_eq!(t.report(), "right answers by the runner-up's margin (with RRC): 0–0.01: 0/1, 0.01–0.03: 1/1, 0.03–0.1: 1/1, ≥ 0.1: 1/1, no runner-up: 1/2");
    }
}
