//! Two sweeps of the same episodes, the second with one setting changed: do the outcomes
//! stay the same in distribution?
//!
//! The same in distribution means, at once: each outcome's rate (goal, active and passive
//! contact, stall, fault, timeout, stopped) lies inside the other sweep's 95% interval for
//! it (Wilson's score interval), both ways; and the two minimum-clearance distributions pass
//! a two-sample Kolmogorov-Smirnov test at the 1% level.

use serde::Serialize;

use super::Episode;
use crate::lab::Outcome;

/// The normal quantile of a two-sided 95% interval.
const Z_95: f64 = 1.959_963_984_540_054;
/// The Kolmogorov-Smirnov test's level: distributions differ below this p-value.
pub const KS_LEVEL: f64 = 0.01;

/// One outcome's rate in both sweeps.
#[derive(Debug, Clone, Serialize)]
pub struct RateComparison {
    pub outcome: &'static str,
    pub before: Interval,
    pub after: Interval,
    /// Each rate inside the other's 95% interval.
    pub same: bool,
}

/// A rate `count / episodes` and its 95% Wilson score interval.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Interval {
    pub count: usize,
    pub episodes: usize,
    pub rate: f64,
    pub low: f64,
    pub high: f64,
}

impl Interval {
    pub fn wilson(count: usize, episodes: usize) -> Self {
        let n = episodes.max(1) as f64;
        let p = count as f64 / n;
        let z2 = Z_95 * Z_95;
        let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
        let half = Z_95 / (1.0 + z2 / n) * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
        // At the ends the interval reaches 0 or 1 exactly (the formula does, but for rounding).
        let low = if count == 0 { 0.0 } else { (centre - half).max(0.0) };
        let high = if count >= episodes { 1.0 } else { (centre + half).min(1.0) };
        Self { count, episodes, rate: p, low, high }
    }

    pub fn contains(&self, rate: f64) -> bool {
        (self.low..=self.high).contains(&rate)
    }
}

/// A two-sample Kolmogorov-Smirnov test.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct KsTest {
    /// The largest gap between the two empirical distribution functions.
    pub statistic: f64,
    /// The chance of a gap this large between samples of one distribution (asymptotic,
    /// with Stephens' correction for the samples' sizes).
    pub p_value: f64,
    pub before: usize,
    pub after: usize,
}

impl KsTest {
    /// `None` when either sample is empty.
    pub fn two_sample(before: &[f64], after: &[f64]) -> Option<Self> {
        if before.is_empty() || after.is_empty() {
            return None;
        }
        let sorted = |s: &[f64]| {
            let mut v = s.to_vec();
            v.sort_by(f64::total_cmp);
            v
        };
        let (a, b) = (sorted(before), sorted(after));
        let (n, m) = (a.len() as f64, b.len() as f64);
        let (mut i, mut j, mut statistic) = (0, 0, 0.0f64);
        while i < a.len() && j < b.len() {
            // Step past every sample equal to the smaller value, in both, before comparing.
            let x = a[i].min(b[j]);
            while i < a.len() && a[i] <= x {
                i += 1;
            }
            while j < b.len() && b[j] <= x {
                j += 1;
            }
            statistic = statistic.max((i as f64 / n - j as f64 / m).abs());
        }
        let effective = (n * m / (n + m)).sqrt();
        let p_value = kolmogorov_q((effective + 0.12 + 0.11 / effective) * statistic);
        Some(Self { statistic, p_value, before: a.len(), after: b.len() })
    }
}

/// The Kolmogorov distribution's tail, `Q(λ) = 2 Σ (-1)^(k-1) exp(-2 k² λ²)`, by the series
/// that converges fast on each side of 1.18.
pub fn kolmogorov_q(lambda: f64) -> f64 {
    if lambda <= 0.0 {
        return 1.0;
    }
    if lambda < 1.18 {
        let y = (-std::f64::consts::PI.powi(2) / (8.0 * lambda * lambda)).exp();
        let sum = y + y.powi(9) + y.powi(25) + y.powi(49);
        (1.0 - (2.0 * std::f64::consts::PI).sqrt() / lambda * sum).clamp(0.0, 1.0)
    } else {
        let x = (-2.0 * lambda * lambda).exp();
        (2.0 * (x - x.powi(4) + x.powi(9))).clamp(0.0, 1.0)
    }
}

/// The two sweeps side by side.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub rates: Vec<RateComparison>,
    /// The minimum clearances' test (`None`: an episode set without obstacles).
    pub clearance: Option<KsTest>,
    /// Every rate inside the other's interval, and the clearances' p-value at or above
    /// [`KS_LEVEL`].
    pub same: bool,
}

/// Whether an episode ended so.
type Is = fn(&Episode) -> bool;

/// Compare `before` and `after`, the same episodes of two sweeps.
pub fn compare(before: &[Episode], after: &[Episode]) -> Comparison {
    let outcomes: [(&'static str, Is); 7] = [
        ("goal", |e| e.outcome == Outcome::Goal),
        ("active contact", |e| e.active_contact),
        ("passive contact", Episode::passive_contact),
        ("stall", |e| e.outcome == Outcome::Stall),
        ("fault", |e| e.outcome == Outcome::Fault),
        ("timeout", |e| e.outcome == Outcome::Timeout),
        ("stopped", |e| e.outcome == Outcome::Stopped),
    ];
    let rates: Vec<RateComparison> = outcomes
        .iter()
        .map(|&(outcome, is)| {
            let interval = |es: &[Episode]| Interval::wilson(es.iter().filter(|e| is(e)).count(), es.len());
            let (before, after) = (interval(before), interval(after));
            RateComparison { outcome, before, after, same: before.contains(after.rate) && after.contains(before.rate) }
        })
        .collect();
    let clearances = |es: &[Episode]| es.iter().filter_map(|e| e.min_clearance).collect::<Vec<f64>>();
    let clearance = KsTest::two_sample(&clearances(before), &clearances(after));
    let same = rates.iter().all(|r| r.same) && clearance.is_none_or(|k| k.p_value >= KS_LEVEL);
    Comparison { rates, clearance, same }
}

impl std::fmt::Display for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pc = |x: f64| 100.0 * x;
        writeln!(f, "  {:<16} {:>26} {:>26}  inside each other's", "outcome", "as given (95%)", "changed (95%)")?;
        for r in &self.rates {
            let cell = |i: &Interval| format!("{:.2}% [{:.2}, {:.2}]", pc(i.rate), pc(i.low), pc(i.high));
            let same = if r.same { "yes" } else { "NO" };
            writeln!(f, "  {:<16} {:>26} {:>26}  {same}", r.outcome, cell(&r.before), cell(&r.after))?;
        }
        match &self.clearance {
            Some(k) => writeln!(
                f,
                "  min clearance: Kolmogorov-Smirnov D = {:.4}, p = {:.3} ({} and {} episodes; the same at the 1% level: {})",
                k.statistic,
                k.p_value,
                k.before,
                k.after,
                if k.p_value >= KS_LEVEL { "yes" } else { "NO" }
            )?,
            None => writeln!(f, "  min clearance: no obstacle in either sweep")?,
        }
        write!(f, "  the same in distribution: {}", if self.same { "yes" } else { "NO" })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Kolmogorov distribution's known critical values: λ = 1.358 at 5%, 1.628 at 1%.
    #[test]
    fn the_kolmogorov_tail_gives_the_known_critical_values() {
        assert!((kolmogorov_q(1.358) - 0.05).abs() < 5e-4, "{}", kolmogorov_q(1.358));
        assert!((kolmogorov_q(1.628) - 0.01).abs() < 2e-4, "{}", kolmogorov_q(1.628));
        // Both series agree where they meet.
        assert!((kolmogorov_q(1.18 - 1e-9) - kolmogorov_q(1.18)).abs() < 1e-6);
        assert_eq!(kolmogorov_q(0.0), 1.0);
    }

    #[test]
    fn two_samples_of_one_distribution_pass_and_shifted_ones_fail() {
        let a: Vec<f64> = (0..1000).map(|k| f64::from(k) / 1000.0).collect();
        let b: Vec<f64> = (0..1000).map(|k| (f64::from(k) + 0.5) / 1000.0).collect();
        let same = KsTest::two_sample(&a, &b).unwrap();
        assert!(same.statistic <= 0.001 + 1e-12 && same.p_value > 0.99, "{same:?}");
        let shifted: Vec<f64> = a.iter().map(|x| x + 0.1).collect();
        let moved = KsTest::two_sample(&a, &shifted).unwrap();
        assert!((moved.statistic - 0.1).abs() < 2e-3 && moved.p_value < 1e-3, "{moved:?}");
        // Ties count together: identical samples have no gap at all.
        let ties = KsTest::two_sample(&[1.0, 1.0, 2.0], &[1.0, 1.0, 2.0]).unwrap();
        assert_eq!((ties.statistic, ties.p_value), (0.0, 1.0));
        assert!(KsTest::two_sample(&[], &a).is_none());
    }

    /// Wilson's interval against values worked by hand: 50 of 100 is 40.4-59.6%, 0 of 10,000
    /// is 0-0.038%.
    #[test]
    fn wilson_intervals_match_worked_values() {
        let half = Interval::wilson(50, 100);
        assert!((half.low - 0.4038).abs() < 1e-4 && (half.high - 0.5962).abs() < 1e-4, "{half:?}");
        let none = Interval::wilson(0, 10_000);
        assert!(none.low == 0.0 && (none.high - 3.84e-4).abs() < 1e-6, "{none:?}");
        assert!(none.contains(0.0) && !none.contains(0.001));
    }

    fn episode(index: u64, outcome: Outcome, clearance: f64) -> Episode {
        Episode {
            index,
            outcome,
            min_clearance: Some(clearance),
            speed_ratio: 0.5,
            delay: 0.1,
            active_contact: false,
            min_wall_clearance: None,
            duration: 10.0,
            path_length: 1.0,
            discomfort: 0.0,
        }
    }

    #[test]
    fn a_changed_goal_rate_or_clearance_is_not_the_same() {
        let before: Vec<_> = (0..1000).map(|k| episode(k, Outcome::Goal, 0.05 + k as f64 * 1e-5)).collect();
        assert!(compare(&before, &before).same);
        // One in ten stalls instead: the goal rate leaves the interval.
        let stalling: Vec<_> = before
            .iter()
            .map(|e| if e.index % 10 == 0 { Episode { outcome: Outcome::Stall, ..*e } } else { *e })
            .collect();
        let c = compare(&before, &stalling);
        assert!(!c.same && !c.rates[0].same && !c.rates[3].same, "{c}");
        // Every clearance 5 mm closer: the rates hold, the distribution does not.
        let closer: Vec<_> =
            before.iter().map(|e| Episode { min_clearance: e.min_clearance.map(|c| c - 0.005), ..*e }).collect();
        let c = compare(&before, &closer);
        assert!(c.rates.iter().all(|r| r.same) && !c.same, "{c}");
    }
}
