//! The clearance of a pose among the obstacles, and the pairs near contact with gradients.
//!
//! The clearance of the pair (link `i`, obstacle `k`) is the signed distance from the link's
//! axis `p_{i-1} p_i` to the obstacle (see [`super::geometry`]) minus the world's
//! `link_radius_m`: the gap between the capsule and the obstacle, negative when they overlap.
//! A pose keeps the world's `clearance_m` when every pair's clearance is at least that.
//!
//! For a solver each pair near contact comes with the gradient of its clearance with respect
//! to the joint angles. The contact point `q` on link `i` is carried by joints `1..=i`; turning
//! joint `j` (at `p_{j-1}`) moves it by `perp(q - p_{j-1})` per radian, so
//! `d clearance / d theta_j = normal . perp(q - p_{j-1}) = cross(q - p_{j-1}, normal)` for
//! `j <= i` and 0 beyond. Away from the places where the nearest features switch, this is the
//! exact derivative (the contact's parameter along the link may be held: envelope theorem),
//! except for a link through a polygon whose deepest point found is a stretch's middle (see
//! [`super::geometry`]): there it is the direction that pushes the link out.
//!
//! The per-tick paths take the pose's points (`Chain::points_into`) and fill the caller's
//! buffers, so a warm loop allocates nothing; boxes around each obstacle skip far pairs.

use super::geometry::{cross, Contact};
use super::World;
use crate::chain::{Chain, Vec2};

/// The nearest approach of one link and one obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pair {
    /// The link, 1-based from the base (link `i` runs from `p_{i-1}` to `p_i`).
    pub link: usize,
    /// The obstacle's index in [`World::obstacles`].
    pub obstacle: usize,
    /// Signed distance minus the link radius, m: negative when the capsule overlaps it.
    pub clearance_m: f64,
    /// Where and in which direction (on the link's axis; see [`Contact`]).
    pub contact: Contact,
}

impl Pair {
    /// The obstacle's id.
    pub fn id<'w>(&self, world: &'w World) -> &'w str {
        world
            .obstacles()
            .get(self.obstacle)
            .map_or("", |o| o.id.as_str())
    }
}

/// The pairs within a margin of contact and their gradients; a buffer the caller keeps from
/// tick to tick (it only grows, to at most links x obstacles pairs).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ActivePairs {
    pairs: Vec<Pair>,
    gradients: Vec<f64>,
    joints: usize,
}

impl ActivePairs {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// A buffer that holds `pairs` pairs of a `joints`-joint chain without allocating.
    pub fn with_capacity(pairs: usize, joints: usize) -> Self {
        Self {
            pairs: Vec::with_capacity(pairs),
            gradients: Vec::with_capacity(pairs * joints),
            joints,
        }
    }

    /// Number of pairs found.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    /// True when no pair is near contact.
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// Joints of the chain the gradients are for.
    pub fn joints(&self) -> usize {
        self.joints
    }

    /// The pairs, in order of link then obstacle.
    pub fn pairs(&self) -> &[Pair] {
        &self.pairs
    }

    /// Pair `k`'s gradient: `d clearance_m / d theta_j`, one entry per joint.
    ///
    /// # Panics
    /// If `k >= len()`.
    pub fn gradient(&self, k: usize) -> &[f64] {
        &self.gradients[k * self.joints..(k + 1) * self.joints]
    }

    /// Each pair with its gradient.
    pub fn iter(&self) -> impl Iterator<Item = (&Pair, &[f64])> {
        self.pairs
            .iter()
            .zip(self.gradients.chunks_exact(self.joints.max(1)))
    }

    fn clear(&mut self, joints: usize) {
        self.pairs.clear();
        self.gradients.clear();
        self.joints = joints;
    }
}

/// Writes the gradient of `pair`'s clearance with respect to the joint angles of the pose whose
/// points are `points` (`p_0..p_n`) into `out` (n entries).
///
/// # Panics
/// If `out.len() + 1 != points.len()` or the pair's link is not a link of the pose.
pub fn pair_gradient(points: &[Vec2], pair: &Pair, out: &mut [f64]) {
    assert_eq!(out.len() + 1, points.len(), "one entry per joint");
    assert!((1..points.len()).contains(&pair.link), "a link of the pose");
    let q = pair.contact.on_segment;
    let n = pair.contact.normal;
    for (j, g) in out.iter_mut().enumerate() {
        *g = if j < pair.link {
            cross(q - points[j], n)
        } else {
            0.0
        };
    }
}

/// Links whose common box [`World::near_pairs`] checks an obstacle against first.
pub const LINK_GROUP: usize = 4;

/// The box of a run of points (a group of links).
fn group_box(points: &[Vec2]) -> (Vec2, Vec2) {
    points
        .iter()
        .fold((points[0], points[0]), |(lo, hi), p| (lo.inf(p), hi.sup(p)))
}

fn segment_box(a: Vec2, b: Vec2) -> (Vec2, Vec2) {
    (a.inf(&b), a.sup(&b))
}

impl World {
    /// The pair (link `link`, 1-based; obstacle index `obstacle`) of the pose `points`.
    ///
    /// # Panics
    /// If either is out of range.
    pub fn pair(&self, points: &[Vec2], link: usize, obstacle: usize) -> Pair {
        let contact = self.obstacles[obstacle]
            .shape
            .segment_contact(points[link - 1], points[link]);
        Pair {
            link,
            obstacle,
            clearance_m: contact.distance_m - self.link_radius_m,
            contact,
        }
    }

    /// The pair of least clearance of the pose whose points are `points` (`p_0..p_n`), or
    /// `None` when the world has no obstacles. Allocation-free.
    pub fn clearance(&self, points: &[Vec2]) -> Option<Pair> {
        let mut best: Option<Pair> = None;
        for link in 1..points.len() {
            let (lo, hi) = segment_box(points[link - 1], points[link]);
            for k in 0..self.obstacles.len() {
                if let Some(b) = &best {
                    // The boxes' gap bounds the distance from below.
                    if self.box_not_below(k, lo, hi, b.clearance_m + self.link_radius_m) {
                        continue;
                    }
                }
                let p = self.pair(points, link, k);
                if best.is_none_or(|b| p.clearance_m < b.clearance_m) {
                    best = Some(p);
                }
            }
        }
        best
    }

    /// [`World::clearance`], the pair `hint` (link, obstacle) looked at first: when it is near
    /// the least, its clearance bounds the search so tightly that the boxes skip almost every
    /// other pair ([`World::clearance_below`]). The same least clearance, bit for bit, whatever
    /// the hint (in a tie, the hint's pair may be the one named). A hint out of range is
    /// ignored. Allocation-free.
    pub fn clearance_from(&self, points: &[Vec2], hint: Option<(usize, usize)>) -> Option<Pair> {
        let valid = |&(link, k): &(usize, usize)| {
            (1..points.len()).contains(&link) && k < self.obstacles.len()
        };
        let Some((link, k)) = hint.filter(valid) else {
            return self.clearance(points);
        };
        let first = self.pair(points, link, k);
        if first.clearance_m.is_nan() {
            return self.clearance(points);
        }
        Some(
            self.clearance_below(points, first.clearance_m)
                .unwrap_or(first),
        )
    }

    /// The pair of least clearance of the pose `points` when that clearance is below `floor_m`,
    /// else `None`: what a caller that only needs `min(floor_m, clearance)` asks, with every
    /// link group and link whose box is `floor_m` or more from an obstacle's box skipped (as
    /// in [`World::near_pairs`]). Allocation-free.
    pub fn clearance_below(&self, points: &[Vec2], floor_m: f64) -> Option<Pair> {
        let mut best: Option<Pair> = None;
        let links = points.len().saturating_sub(1);
        let mut first = 1;
        while first <= links {
            let last = (first + LINK_GROUP - 1).min(links);
            let (glo, ghi) = group_box(&points[first - 1..=last]);
            for k in 0..self.obstacles.len() {
                let bound = best.map_or(floor_m, |b| b.clearance_m) + self.link_radius_m;
                if self.box_not_below(k, glo, ghi, bound) {
                    continue;
                }
                for link in first..=last {
                    let bound = best.map_or(floor_m, |b| b.clearance_m) + self.link_radius_m;
                    let (lo, hi) = segment_box(points[link - 1], points[link]);
                    if self.box_not_below(k, lo, hi, bound) {
                        continue;
                    }
                    let p = self.pair(points, link, k);
                    if p.clearance_m < best.map_or(floor_m, |b| b.clearance_m) {
                        best = Some(p);
                    }
                }
            }
            first = last + 1;
        }
        best
    }

    /// [`World::clearance`] of the pose `theta` of `chain` (allocates the points).
    pub fn pose_clearance(&self, chain: &Chain, theta: &[f64]) -> Option<Pair> {
        self.clearance(&chain.points(theta))
    }

    /// Per pair of link and obstacle, the floor a new pose must keep: `min(keep_m, the pair's
    /// clearance in points)` into `out[(link - 1) * m + k]` (`m` obstacles, `k` the obstacle's
    /// index), with `keep_m` for a pair far apart (so a clear pair must stay clear, and a pair
    /// not clear may only get clearer: a link inside one obstacle is not thereby free to enter
    /// another). `out` holds `links * m` floors. Allocation-free.
    pub fn link_floors(&self, points: &[Vec2], keep_m: f64, out: &mut [f64]) {
        let m = self.obstacles.len();
        for link in 1..points.len() {
            let (lo, hi) = segment_box(points[link - 1], points[link]);
            for k in 0..m {
                let Some(floor) = out.get_mut((link - 1) * m + k) else {
                    return;
                };
                *floor = keep_m;
                if self.box_not_below(k, lo, hi, keep_m + self.link_radius_m) {
                    continue;
                }
                *floor = floor.min(self.pair(points, link, k).clearance_m);
            }
        }
    }

    /// The first pair of the pose `points` whose clearance is below its floor
    /// (`floors[(link - 1) * m + k]`, see [`World::link_floors`]), or `None`. Allocation-free.
    pub fn below_floors(&self, points: &[Vec2], floors: &[f64]) -> Option<Pair> {
        self.below_floors_by(points, floors, 0.0)
    }

    /// As [`World::below_floors`], each floor lowered by `slack_m`. Allocation-free.
    pub fn below_floors_by(&self, points: &[Vec2], floors: &[f64], slack_m: f64) -> Option<Pair> {
        let m = self.obstacles.len();
        for link in 1..points.len() {
            let (lo, hi) = segment_box(points[link - 1], points[link]);
            for k in 0..m {
                let floor = floors.get((link - 1) * m + k)? - slack_m;
                if self.box_not_below(k, lo, hi, floor + self.link_radius_m) {
                    continue;
                }
                let p = self.pair(points, link, k);
                if p.clearance_m < floor {
                    return Some(p);
                }
            }
        }
        None
    }

    /// How far any point of the pose `points` may move, m, before a pair could fall below its
    /// floor (see [`World::below_floors`]): the least of `cap_m` and each pair's clearance above
    /// its floor, since a pair's distance changes by no more than its link's points move. 0
    /// when it cannot vouch for any move: a pair below or on its floor, or meeting its obstacle
    /// (a depth inside is found by sampling). Pairs whose boxes are farther than the answer are
    /// skipped. Allocation-free.
    pub fn free_sweep(&self, points: &[Vec2], floors: &[f64], cap_m: f64) -> f64 {
        let m = self.obstacles.len();
        let mut free = cap_m.max(0.0);
        for link in 1..points.len() {
            let (lo, hi) = segment_box(points[link - 1], points[link]);
            for k in 0..m {
                let Some(&floor) = floors.get((link - 1) * m + k) else {
                    return 0.0;
                };
                if self.box_not_below(k, lo, hi, floor + free + self.link_radius_m) {
                    continue;
                }
                let p = self.pair(points, link, k);
                let excess = p.clearance_m - floor;
                // Written so that a NaN cannot vouch either.
                if !(p.contact.distance_m > 0.0 && excess > 0.0) {
                    return 0.0;
                }
                free = free.min(excess);
            }
        }
        free
    }

    /// The pair of the pose `points` whose clearance is least among those below their floors
    /// (see [`World::below_floors`]): the deepest a link would go, or `None`. Allocation-free.
    pub fn deepest_below_floors(&self, points: &[Vec2], floors: &[f64]) -> Option<Pair> {
        let m = self.obstacles.len();
        let mut deepest: Option<Pair> = None;
        for link in 1..points.len() {
            let (lo, hi) = segment_box(points[link - 1], points[link]);
            for k in 0..m {
                let floor = *floors.get((link - 1) * m + k)?;
                // Only a pair below its floor and below the deepest so far counts.
                let bar = deepest.as_ref().map_or(floor, |d| floor.min(d.clearance_m));
                if self.box_not_below(k, lo, hi, bar + self.link_radius_m) {
                    continue;
                }
                let p = self.pair(points, link, k);
                if p.clearance_m < bar {
                    deepest = Some(p);
                }
            }
        }
        deepest
    }

    /// Fills `out` with every pair of the pose `points` (`p_0..p_n`) whose clearance is at most
    /// `margin_m`, each with its gradient (see the module doc). Allocation-free once `out` has
    /// held as many pairs.
    pub fn active_pairs(&self, points: &[Vec2], margin_m: f64, out: &mut ActivePairs) {
        let joints = points.len().saturating_sub(1);
        out.clear(joints);
        self.near_pairs(points, margin_m, &mut out.pairs);
        out.pairs.sort_unstable_by_key(|p| (p.link, p.obstacle));
        out.gradients.resize(out.pairs.len() * joints, 0.0);
        for (p, g) in out
            .pairs
            .iter()
            .zip(out.gradients.chunks_exact_mut(joints.max(1)))
        {
            pair_gradient(points, p, g);
        }
    }

    /// Fills `out` with every pair of the pose `points` whose clearance is at most `margin_m`,
    /// without their gradients, a group of links at a time (obstacle by obstacle within it). Links are first taken
    /// [`LINK_GROUP`] at a time: an obstacle whose box is beyond the margin from the group's
    /// box is beyond it from each of the group's links.
    pub fn near_pairs(&self, points: &[Vec2], margin_m: f64, out: &mut Vec<Pair>) {
        out.clear();
        let reach = margin_m + self.link_radius_m;
        let links = points.len().saturating_sub(1);
        let mut first = 1;
        while first <= links {
            let last = (first + LINK_GROUP - 1).min(links);
            let (glo, ghi) = group_box(&points[first - 1..=last]);
            for k in 0..self.obstacles.len() {
                if self.box_beyond(k, glo, ghi, reach) {
                    continue;
                }
                for link in first..=last {
                    let (lo, hi) = segment_box(points[link - 1], points[link]);
                    if self.box_beyond(k, lo, hi, reach) {
                        continue;
                    }
                    let p = self.pair(points, link, k);
                    if p.clearance_m <= margin_m {
                        out.push(p);
                    }
                }
            }
            first = last + 1;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::super::geometry::DEPTH_SAMPLES;
    use super::super::{Obstacle, Shape};
    use super::*;
    use proptest::prelude::*;

    fn v(x: f64, y: f64) -> Vec2 {
        Vec2::new(x, y)
    }

    fn world() -> World {
        World::new(
            0.02,
            0.01,
            vec![
                Obstacle {
                    id: "post".into(),
                    shape: Shape::Circle {
                        center: v(0.25, 0.12),
                        radius_m: 0.04,
                    },
                },
                Obstacle {
                    id: "shelf".into(),
                    shape: Shape::Polygon {
                        points: vec![
                            v(0.05, -0.2),
                            v(0.35, -0.2),
                            v(0.35, -0.12),
                            v(0.2, -0.15),
                            v(0.05, -0.1),
                        ],
                    },
                },
            ],
        )
        .unwrap()
    }

    fn chain() -> Chain {
        Chain::unlimited(vec![0.1, 0.1, 0.08, 0.06], Vec2::zeros(), 0.0).unwrap()
    }

    #[test]
    fn least_clearance_names_the_link_and_obstacle() {
        let (w, c) = (world(), chain());
        // Straight along x, 0.34 long: link 3 (0.2..0.28) passes 0.12 under the post's centre.
        let p = w.pose_clearance(&c, &[0.0; 4]).unwrap();
        assert_eq!(p.id(&w), "post");
        assert_eq!(p.link, 3);
        assert!(
            (p.clearance_m - (0.12 - 0.04 - 0.02)).abs() < 1e-12,
            "{}",
            p.clearance_m
        );
        // Bent up into the post: overlapping, negative.
        let p = w.pose_clearance(&c, &[0.5, 0.0, 0.0, 0.0]).unwrap();
        assert!(p.clearance_m < -0.02, "{p:?}");
        // Bent down into the shelf.
        let p = w.pose_clearance(&c, &[-0.9, 0.0, 0.0, 0.0]).unwrap();
        assert_eq!(p.id(&w), "shelf");
        assert!(p.clearance_m < 0.0);
        let empty = World::new(0.0, 0.0, vec![]).unwrap();
        assert_eq!(empty.pose_clearance(&c, &[0.0; 4]), None);
    }

    #[test]
    fn the_least_clearance_is_the_least_pair() {
        let (w, c) = (world(), chain());
        for theta in [
            [0.0; 4],
            [0.4, -0.3, 0.2, 0.9],
            [-0.7, 0.3, 0.3, 0.3],
            [0.2, 0.2, -1.5, 2.0],
        ] {
            let pts = c.points(&theta);
            let best = w.clearance(&pts).unwrap();
            for link in 1..=4 {
                for k in 0..2 {
                    assert!(w.pair(&pts, link, k).clearance_m >= best.clearance_m);
                }
            }
        }
    }

    /// A disc of radius 0.04 at (`x`, `y`) named `id`.
    fn disc(id: &str, x: f64, y: f64) -> Obstacle {
        Obstacle {
            id: id.into(),
            shape: Shape::Circle {
                center: v(x, y),
                radius_m: 0.04,
            },
        }
    }

    #[test]
    fn the_deepest_pair_is_found_past_a_link_whose_axis_is_inside_an_obstacle() {
        // Links of 0.1 along x, radius 0.02. Link 1's axis passes 0.035 from the first disc's
        // centre (0.005 inside it: clearance -0.025, past the link radius); link 3's passes
        // through the second disc's centre (clearance -0.04 - 0.02).
        let w = World::new(
            0.02,
            0.01,
            vec![disc("shallow", 0.05, 0.035), disc("deep", 0.25, 0.0)],
        )
        .unwrap();
        let pts = [v(0.0, 0.0), v(0.1, 0.0), v(0.2, 0.0), v(0.3, 0.0)];
        let p = w.clearance(&pts).unwrap();
        assert_eq!((p.link, p.id(&w)), (3, "deep"), "{p:?}");
        assert!((p.clearance_m + 0.06).abs() < 1e-12, "{}", p.clearance_m);
        let hinted = w.clearance_from(&pts, Some((1, 0))).unwrap();
        assert_eq!(hinted.clearance_m, p.clearance_m);
    }

    #[test]
    fn a_link_inside_an_obstacle_may_not_go_deeper() {
        // One link whose axis is 0.03 from a disc's centre (clearance -0.03), then 0.01.
        let w = World::new(0.02, 0.01, vec![disc("post", 0.05, 0.03)]).unwrap();
        let now = [v(0.0, 0.0), v(0.1, 0.0)];
        let mut floors = [0.0];
        w.link_floors(&now, 0.01, &mut floors);
        assert!((floors[0] + 0.03).abs() < 1e-12, "{floors:?}");
        let deeper = [v(0.0, 0.02), v(0.1, 0.02)];
        let hit = w.below_floors(&deeper, &floors).unwrap();
        assert_eq!((hit.link, hit.id(&w)), (1, "post"));
        assert!(hit.clearance_m < floors[0]);
        // Out of it a little is allowed.
        let out = [v(0.0, -0.01), v(0.1, -0.01)];
        assert_eq!(w.below_floors(&out, &floors), None);
    }

    #[test]
    fn the_deepest_pair_below_its_floor_is_found_not_the_first() {
        // Link 1 grazes "shallow" (clearance 0.005, below 0.01); link 3 runs through "deep".
        let w = World::new(
            0.01,
            0.01,
            vec![disc("shallow", 0.05, 0.055), disc("deep", 0.25, 0.0)],
        )
        .unwrap();
        let pts = [v(0.0, 0.0), v(0.1, 0.0), v(0.2, 0.0), v(0.3, 0.0)];
        let floors = [0.01; 6];
        let first = w.below_floors(&pts, &floors).unwrap();
        assert_eq!((first.link, first.id(&w)), (1, "shallow"));
        let deepest = w.deepest_below_floors(&pts, &floors).unwrap();
        assert_eq!((deepest.link, deepest.id(&w)), (3, "deep"), "{deepest:?}");
        assert_eq!(deepest.clearance_m, w.clearance(&pts).unwrap().clearance_m);
        // A floor below a pair's clearance lets it be: the graze alone is left.
        let let_deep = [0.01, 0.01, 0.01, -1.0, 0.01, -1.0];
        let only = w.deepest_below_floors(&pts, &let_deep).unwrap();
        assert_eq!((only.link, only.id(&w)), (1, "shallow"), "{only:?}");
        assert_eq!(w.deepest_below_floors(&pts, &[-1.0; 6]), None);
    }

    #[test]
    fn active_pairs_are_those_within_the_margin() {
        let (w, c) = (world(), chain());
        let theta = [0.0, 0.3, 0.0, 0.0];
        let pts = c.points(&theta);
        let mut buf = ActivePairs::with_capacity(8, 4);
        w.active_pairs(&pts, 0.05, &mut buf);
        assert!(!buf.is_empty());
        for link in 1..=4 {
            for k in 0..2 {
                let p = w.pair(&pts, link, k);
                let listed = buf
                    .pairs()
                    .iter()
                    .any(|q| q.link == link && q.obstacle == k);
                assert_eq!(listed, p.clearance_m <= 0.05, "link {link} obstacle {k}");
            }
        }
        // Refilled, not appended.
        w.active_pairs(&pts, -1.0, &mut buf);
        assert!(buf.is_empty());
    }

    fn check_gradients(w: &World, c: &Chain, theta: &[f64]) -> usize {
        let pts = c.points(theta);
        let mut buf = ActivePairs::new();
        w.active_pairs(&pts, 1.0, &mut buf);
        let mut checked = 0;
        for (p, g) in buf.iter() {
            // A stretch's middle moves with the crossings: a push direction, not a derivative.
            let sample = p.contact.s * DEPTH_SAMPLES as f64;
            if p.contact.distance_m < 0.0 && p.obstacle == 1 && sample != sample.round() {
                continue;
            }
            let h = 1e-7;
            for j in 0..theta.len() {
                let mut up = theta.to_vec();
                let mut down = theta.to_vec();
                up[j] += h;
                down[j] -= h;
                let fu = w.pair(&c.points(&up), p.link, p.obstacle).clearance_m;
                let fd = w.pair(&c.points(&down), p.link, p.obstacle).clearance_m;
                let f0 = p.clearance_m;
                // Where the nearest features switch the distance has a kink: the two one-sided
                // slopes differ and neither is the gradient. Test the smooth places.
                if ((fu - f0) - (f0 - fd)).abs() > 1e-9 {
                    continue;
                }
                let fdiff = (fu - fd) / (2.0 * h);
                assert!(
                    (fdiff - g[j]).abs() < 1e-6,
                    "link {} obstacle {} joint {j}: {fdiff} vs {}",
                    p.link,
                    p.obstacle,
                    g[j]
                );
                checked += 1;
            }
        }
        checked
    }

    #[test]
    fn gradients_match_finite_differences_apart_and_inside() {
        let (w, c) = (world(), chain());
        let mut checked = 0;
        for theta in [
            [0.0; 4],
            [0.5, 0.0, 0.0, 0.0],
            [-0.9, 0.1, 0.2, 0.0],
            [0.3, -0.6, 0.9, -0.4],
            [-0.4, -0.4, 0.8, 0.8],
        ] {
            checked += check_gradients(&w, &c, &theta);
        }
        assert!(checked >= 40, "only {checked} derivatives were checked");
    }

    #[test]
    fn a_link_through_a_corner_is_pushed_out_by_its_gradient() {
        let square = Obstacle {
            id: "box".into(),
            shape: Shape::Polygon {
                points: vec![v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0)],
            },
        };
        let w = World::new(0.0, 0.0, vec![square]).unwrap();
        // One long link along x + y = 1.98, cutting the corner at (1, 1) between samples.
        let (a, b) = (v(9.3, -7.32), v(-6.72, 8.7));
        let c = Chain::unlimited(vec![(b - a).norm()], a, 0.75 * std::f64::consts::PI).unwrap();
        let theta = [0.0];
        let before = w.pose_clearance(&c, &theta).unwrap();
        assert!(before.clearance_m < -0.009, "{before:?}");
        let mut buf = ActivePairs::new();
        w.active_pairs(&c.points(&theta), 0.0, &mut buf);
        assert_eq!(buf.len(), 1);
        let g = buf.gradient(0)[0];
        assert!(g != 0.0);
        let after = w.pose_clearance(&c, &[1e-4 * g.signum()]).unwrap();
        assert!(after.clearance_m > before.clearance_m, "{after:?}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn gradients_match_finite_differences(theta in proptest::collection::vec(-1.5..1.5f64, 4)) {
            let (w, c) = (world(), chain());
            // All 8 pairs are active with a 1 m margin; at most a few derivatives sit on a kink.
            prop_assert!(check_gradients(&w, &c, &theta) >= 20);
        }

        #[test]
        fn the_free_sweep_is_the_least_excess_and_no_pose_within_it_falls_below_a_floor(
            start in proptest::collection::vec(-1.2..1.2f64, 4),
            at in proptest::collection::vec(-1.2..1.2f64, 4),
            dir in proptest::collection::vec(-1.0..1.0f64, 4),
        ) {
            let (w, c) = (world(), chain());
            let mut floors = [0.0; 8];
            w.link_floors(&c.points(&start), 0.01, &mut floors);
            let pts = c.points(&at);
            let cap = 0.3;
            let free = w.free_sweep(&pts, &floors, cap);
            // Every pair, looked at one by one.
            let mut least = cap;
            let mut vouch = true;
            for link in 1..=4 {
                for k in 0..2 {
                    let p = w.pair(&pts, link, k);
                    let excess = p.clearance_m - floors[(link - 1) * 2 + k];
                    vouch &= p.contact.distance_m > 0.0 && excess > 0.0;
                    least = least.min(excess);
                }
            }
            if !vouch {
                prop_assert_eq!(free, 0.0);
                return Ok(());
            }
            prop_assert!((free - least).abs() < 1e-15, "{} against {}", free, least);
            let ahead: Vec<f64> = at.iter().zip(&dir).map(|(a, d)| a + d).collect();
            let per_unit = c.sweep(&at, &ahead);
            prop_assume!(per_unit > 0.0);
            for f in [0.1, 0.3, 0.5, 0.7, 0.9, 1.0] {
                let s = f * free / per_unit;
                let theta: Vec<f64> = at.iter().zip(&dir).map(|(a, d)| a + s * d).collect();
                let hit = w.below_floors(&c.points(&theta), &floors);
                prop_assert!(hit.is_none(), "{:?} at {} of the free sweep {}", hit, f, free);
            }
        }
    }
}
