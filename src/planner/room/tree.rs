//! The room's panels grouped for evaluation: a binary tree over their loop order, each node
//! holding a run of consecutive panels and the disc that contains them. A point far from a
//! node (beyond `1/THETA` of its radius) takes the node's panels' flow from one multipole
//! expansion about the disc's centre (a treecode); a point near it goes down to its
//! children, and at a leaf to the panels themselves. The nearest panel is found by the same
//! walk, skipping each disc that cannot hold a panel near enough.
//!
//! A panel's flow `(σ/t) Log((z - a)/(z - b))` is analytic outside any disc holding the
//! panel and vanishes at infinity, so about the disc's centre `c` it is exactly
//! `Σ_k M_k / (z - c)^k`, with `M_k = (σ/t) ((b - c)^k - (a - c)^k) / k`. Its `k`-th term is
//! at most `(L/R) θ^(k-1)` for a disc of radius `ρ` and `R = |z - c| ≥ ρ/θ`, so stopping
//! after `ORDER` terms errs by at most `(L/R) θ^ORDER / (1 - θ)` a unit density.

use crate::Point;

use super::Panel;

/// The number of terms kept of a node's expansion.
pub const ORDER: usize = 18;
/// A node's expansion stands for its panels at points at least `1/THETA` of its radius from
/// its centre. With `ORDER`, each unit of density and length at distance `R` errs by at
/// most `θ^ORDER / (1 - θ) / R`: 1.85e-6 (the series of a lone panel, beyond 8 lengths:
/// 3.05e-6).
pub const THETA: f64 = 0.45;
/// The most panels a leaf holds.
const LEAF: usize = 8;

/// One node: the panels `first..end` (consecutive along the boundary's loops), the disc
/// holding them, and where the walk goes on when it does not enter the node.
#[derive(Debug, Clone, PartialEq)]
struct Node {
    first: usize,
    end: usize,
    center: Point,
    radius: f64,
    /// `(radius / THETA)²`: beyond it the expansion stands for the node; infinite where
    /// expansions are not used.
    far_sqr: f64,
    /// The index of the node after this one's subtree (its first child is the next index).
    next: usize,
}

impl Node {
    fn leaf(&self) -> bool {
        self.end - self.first <= LEAF
    }
}

/// The tree, in preorder.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PanelTree {
    nodes: Vec<Node>,
    /// Whether the nodes' expansions stand for their panels far away.
    multipole: bool,
}

impl PanelTree {
    pub fn new(panels: &[Panel], multipole: bool) -> Self {
        let mut tree = Self { nodes: Vec::with_capacity(2 * panels.len() / LEAF + 2), multipole };
        if !panels.is_empty() {
            tree.push(panels, 0, panels.len());
        }
        tree
    }

    fn push(&mut self, panels: &[Panel], first: usize, end: usize) {
        let ends = || panels[first..end].iter().flat_map(|p| [p.a, p.b]);
        let (lo, hi) = ends().fold((Point::new(f64::MAX, f64::MAX), Point::new(f64::MIN, f64::MIN)), |(lo, hi), z| {
            (Point::new(lo.re.min(z.re), lo.im.min(z.im)), Point::new(hi.re.max(z.re), hi.im.max(z.im)))
        });
        let center = (lo + hi) * 0.5;
        let radius = ends().map(|z| (z - center).norm()).fold(0.0, f64::max);
        let far_sqr = if self.multipole { (radius / THETA).powi(2) } else { f64::INFINITY };
        let k = self.nodes.len();
        self.nodes.push(Node { first, end, center, radius, far_sqr, next: 0 });
        if end - first > LEAF {
            let half = first + (end - first) / 2;
            self.push(panels, first, half);
            self.push(panels, half, end);
        }
        self.nodes[k].next = self.nodes.len();
    }

    /// How many nodes the tree has (each keeps `ORDER` moments).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Each node's expansion for the panels' `densities`, `ORDER` terms a node into
    /// `moments`: a leaf's from its panels, a parent's by shifting its children's to its
    /// centre (exact to `ORDER` terms). No allocation once `moments` is long enough.
    pub fn expand(&self, panels: &[Panel], densities: &[f64], moments: &mut Vec<Point>) {
        moments.clear();
        if !self.multipole {
            return;
        }
        moments.resize(self.nodes.len() * ORDER, Point::default());
        // Children follow their parent in preorder: backwards, each is ready before it.
        for k in (0..self.nodes.len()).rev() {
            let node = &self.nodes[k];
            let (own, rest) = moments[k * ORDER..].split_at_mut(ORDER);
            if node.leaf() {
                for (panel, &sigma) in panels[node.first..node.end].iter().zip(&densities[node.first..node.end]) {
                    let strength = panel.inverse_direction * sigma;
                    let (a, b) = (panel.a - node.center, panel.b - node.center);
                    let (mut ak, mut bk) = (a, b);
                    for (j, m) in own.iter_mut().enumerate() {
                        *m += strength * (bk - ak) / (j + 1) as f64;
                        ak *= a;
                        bk *= b;
                    }
                }
            } else {
                for child in [k + 1, self.nodes[k + 1].next] {
                    let from = &rest[(child - k - 1) * ORDER..][..ORDER];
                    shift(from, self.nodes[child].center - node.center, own);
                }
            }
        }
    }

    /// The walk every query takes, in preorder: `enter(k, node)` says whether to go into
    /// node `k` (having taken a leaf's panels itself); a node not entered, and a leaf, is
    /// passed over whole.
    fn walk(&self, mut enter: impl FnMut(usize, &Node) -> bool) {
        let mut k = 0;
        while let Some(node) = self.nodes.get(k) {
            k = if enter(k, node) && !node.leaf() { k + 1 } else { node.next };
        }
    }

    /// The flow (`u - i v`) at `z` of the panels with these densities: far nodes by their
    /// `moments` ([`expand`](Self::expand)), near leaves panel by panel.
    pub fn flow(&self, panels: &[Panel], densities: &[f64], moments: &[Point], z: Point) -> Point {
        let mut f = Point::default();
        self.walk(|k, node| {
            let rel = z - node.center;
            let r2 = rel.norm_sqr();
            if r2 > node.far_sqr {
                f += expansion(&moments[k * ORDER..][..ORDER], rel.conj() / r2);
                return false;
            }
            if node.leaf() {
                for (panel, &sigma) in panels[node.first..node.end].iter().zip(&densities[node.first..node.end]) {
                    f += panel.source_flow(z) * sigma;
                }
            }
            true
        });
        f
    }

    /// Calls `visit` with each panel's index and its flow at `z` for a unit density, as
    /// [`flow`](Self::flow) takes it (a far node's panels by their own expansions about its
    /// centre): the rows of the boundary's system, so that the densities solved for make
    /// the flow the field evaluates tangent at the collocation points.
    pub fn unit_flows(&self, panels: &[Panel], z: Point, mut visit: impl FnMut(usize, Point)) {
        self.walk(|_, node| {
            let rel = z - node.center;
            let r2 = rel.norm_sqr();
            let far = r2 > node.far_sqr;
            if !far && !node.leaf() {
                return true;
            }
            let w = rel.conj() / r2;
            for (j, panel) in panels.iter().enumerate().take(node.end).skip(node.first) {
                if !far {
                    visit(j, panel.source_flow(z));
                    continue;
                }
                // Σ ((b - c)^k - (a - c)^k) w^k / k, each power scaled by w: below θ.
                let (a, b) = ((panel.a - node.center) * w, (panel.b - node.center) * w);
                let (mut ak, mut bk, mut sum) = (a, b, Point::default());
                for order in 1..=ORDER {
                    sum += (bk - ak) / order as f64;
                    ak *= a;
                    bk *= b;
                }
                visit(j, sum * panel.inverse_direction);
            }
            false
        });
    }

    /// Calls `visit` with the index of every panel of a node whose disc comes within
    /// `reach` of `p`, in index order: every panel within `reach` of `p` among them.
    pub fn panels_within(&self, p: Point, reach: f64, mut visit: impl FnMut(usize)) {
        self.walk(|_, node| {
            let far = reach + node.radius;
            let near = (p - node.center).norm_sqr() <= far * far;
            if near && node.leaf() {
                (node.first..node.end).for_each(&mut visit);
            }
            near
        });
    }
}

/// `Σ_k m_k w^k`, `k` from 1 (Horner).
#[inline]
fn expansion(m: &[Point], w: Point) -> Point {
    let mut acc = m[ORDER - 1];
    for &c in m[..ORDER - 1].iter().rev() {
        acc = acc * w + c;
    }
    acc * w
}

/// Adds to `to` (about `c`) the expansion `from` (about `c + d`):
/// `(z - c - d)^-k = Σ_{l ≥ k} C(l-1, k-1) d^(l-k) (z - c)^-l`.
fn shift(from: &[Point], d: Point, to: &mut [Point]) {
    let mut powers = [Point::new(1.0, 0.0); ORDER];
    for j in 1..ORDER {
        powers[j] = powers[j - 1] * d;
    }
    for l in 0..ORDER {
        let mut sum = Point::default();
        for k in 0..=l {
            sum += from[k] * powers[l - k] * BINOMIAL[l][k];
        }
        to[l] += sum;
    }
}

/// `BINOMIAL[n][k]` = `C(n, k)`.
const BINOMIAL: [[f64; ORDER]; ORDER] = {
    let mut c = [[0.0; ORDER]; ORDER];
    let mut n = 0;
    while n < ORDER {
        c[n][0] = 1.0;
        let mut k = 1;
        while k <= n {
            c[n][k] = c[n - 1][k - 1] + if k < n { c[n - 1][k] } else { 0.0 };
            k += 1;
        }
        n += 1;
    }
    c
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_binomials_are_pascals() {
        assert_eq!(BINOMIAL[4][..5], [1.0, 4.0, 6.0, 4.0, 1.0]);
        assert_eq!(BINOMIAL[ORDER - 1][ORDER / 2], 24310.0);
    }
}
