//! The per-stage profile the benches print: each stage's share of all the measured time
//! together (sums, not medians, so the shares add up), for choosing the next speed step
//! from data. `other` is what the totals hold beyond the named stages.

/// `rows[i]` holds one measured unit's time per stage, in `names`' order, then its total
/// (ms); `unit` names what a row is ("instances", "frames").
pub(super) fn stage_shares<R: AsRef<[f64]>>(names: &[&str], rows: &[R], unit: &str) -> String {
    let sum = |s: usize| rows.iter().map(|r| r.as_ref().get(s).copied().unwrap_or(0.0)).sum::<f64>();
    let total = sum(names.len());
    if total <= 0.0 {
        return "no time measured".to_string();
    }
    let named: f64 = (0..names.len()).map(sum).sum();
    let mut parts: Vec<String> = names.iter().enumerate().map(|(s, n)| format!("{n} {:.0} %", 100.0 * sum(s) / total)).collect();
    parts.push(format!("other {:.0} %", 100.0 * (total - named).max(0.0) / total));
    format!("{} (of {:.0} ms over {} {unit})", parts.join(", "), total, rows.len())
}

#[cfg(test)]
mod tests {
    /// Shares of the summed time, with what the stages leave of the total as `other`.
    #[test]
    fn each_stage_gets_its_share_of_the_summed_time() {
        let rows = [[10.0, 20.0, 100.0], [10.0, 0.0, 100.0]];
        let p = super::stage_shares(&["a", "b"], &rows, "frames");
        assert_eq!(p, "a 10 %, b 10 %, other 80 % (of 200 ms over 2 frames)");
        assert_eq!(super::stage_shares::<[f64; 3]>(&["a", "b"], &[], "frames"), "no time measured");
    }
}
