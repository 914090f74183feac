//! The Pareto frontier of (cost, error) points, both to be minimised.

/// Indices of the points no other point beats: none is at most as costly and at most as wrong
/// while strictly better in one. Points with a non-finite cost or error are never on it. Of equal
/// points only the first is kept. Returned in order of increasing cost.
pub fn pareto_frontier(points: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].0.is_finite() && points[i].1.is_finite())
        .collect();
    // By cost, then error, then index: the first of a cost is its best, and ties keep the first.
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
            .then(a.cmp(&b))
    });
    let mut out = Vec::new();
    let mut best = f64::INFINITY;
    for i in order {
        if points[i].1 < best {
            best = points[i].1;
            out.push(i);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::pareto_frontier;

    #[test]
    fn keeps_exactly_the_undominated_points() {
        let pts = [
            (1.0, 10.0), // 0: cheapest
            (2.0, 12.0), // 1: dominated by 0
            (2.0, 5.0),  // 2: frontier
            (3.0, 5.0),  // 3: dominated by 2 (same error, dearer)
            (4.0, 1.0),  // 4: frontier
            (5.0, f64::NAN),
            (0.5, f64::INFINITY),
            (6.0, 0.5), // 7: frontier
            (4.0, 1.0), // 8: equal to 4, not repeated
        ];
        assert_eq!(pareto_frontier(&pts), vec![0, 2, 4, 7]);
    }

    #[test]
    fn frontier_points_are_never_dominated_and_others_are() {
        // A deterministic scatter: every frontier point undominated, every other point dominated.
        let pts: Vec<(f64, f64)> = (1..200u64)
            .map(|i| {
                let a = (i.wrapping_mul(2_654_435_761) % 1000) as f64;
                let b = (i.wrapping_mul(40_503) % 997) as f64;
                (a, b)
            })
            .collect();
        let front = pareto_frontier(&pts);
        let dominates = |a: (f64, f64), b: (f64, f64)| a.0 <= b.0 && a.1 <= b.1 && a != b;
        for (i, &p) in pts.iter().enumerate() {
            let dominated = pts.iter().any(|&q| dominates(q, p));
            if front.contains(&i) {
                assert!(!dominated, "frontier point {i} {p:?} is dominated");
            } else {
                let duplicate_of_frontier = front.iter().any(|&f| pts[f] == p);
                assert!(
                    dominated || duplicate_of_frontier,
                    "point {i} {p:?} is neither on the frontier nor dominated"
                );
            }
        }
        assert!(front.len() >= 2);
    }

    #[test]
    fn empty_input_gives_an_empty_frontier() {
        assert!(pareto_frontier(&[]).is_empty());
    }
}
