//! Shadow maps of several sizes in one texture array (issue 22: each light's maps sized from the
//! mismatch factor, not one size per node): every layer is `side`², the side of the largest map.
//! Power-of-two squares are packed into layers largest first, each at the next free position in
//! Z order: largest first keeps every position a multiple of the map's own side, so squares never
//! overlap and no texel is wasted but in the last layer. Sides that are not all powers of two
//! (a fixed size such as 600²) get a layer each. Pure CPU code.

/// Where one map lies: its layer and its square's corner and side, in texels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    pub layer: u32,
    pub x: u32,
    pub y: u32,
    pub side: u32,
}

/// A packing of maps into layers of `side`².
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Atlas {
    /// Layer side: the largest map's (0 when there are no maps).
    pub side: u32,
    /// Layers used.
    pub layers: u32,
    /// One slot per map, in the order of the sides given.
    pub slots: Vec<Slot>,
}

/// Inverse of the Z-order (Morton) interleave of `i`: its even bits are x, its odd bits y.
fn morton_decode(i: u64) -> (u32, u32) {
    let squeeze = |mut v: u64| {
        v &= 0x5555_5555_5555_5555;
        v = (v | (v >> 1)) & 0x3333_3333_3333_3333;
        v = (v | (v >> 2)) & 0x0f0f_0f0f_0f0f_0f0f;
        v = (v | (v >> 4)) & 0x00ff_00ff_00ff_00ff;
        v = (v | (v >> 8)) & 0x0000_ffff_0000_ffff;
        v = (v | (v >> 16)) & 0x0000_0000_ffff_ffff;
        v as u32
    };
    (squeeze(i), squeeze(i >> 1))
}

impl Atlas {
    /// Packs maps of `sides` (0 is taken as 1).
    pub fn pack(sides: &[u32]) -> Atlas {
        let sides: Vec<u32> = sides.iter().map(|&s| s.max(1)).collect();
        let Some(&side) = sides.iter().max() else {
            return Atlas::default();
        };
        if !sides.iter().all(|s| s.is_power_of_two()) {
            return Atlas {
                side,
                layers: sides.len() as u32,
                slots: sides
                    .iter()
                    .enumerate()
                    .map(|(i, &s)| Slot {
                        layer: i as u32,
                        x: 0,
                        y: 0,
                        side: s,
                    })
                    .collect(),
            };
        }
        let mut order: Vec<usize> = (0..sides.len()).collect();
        // Largest first; equal sides keep their order.
        order.sort_by_key(|&i| std::cmp::Reverse(sides[i]));
        let layer_area = u64::from(side) * u64::from(side);
        let mut slots = vec![
            Slot {
                layer: 0,
                x: 0,
                y: 0,
                side: 0
            };
            sides.len()
        ];
        // Texels used so far, in Z order across layers.
        let mut used = 0u64;
        for i in order {
            let s = sides[i];
            let area = u64::from(s) * u64::from(s);
            let layer = used / layer_area;
            let (bx, by) = morton_decode((used % layer_area) / area);
            slots[i] = Slot {
                layer: layer as u32,
                x: bx * s,
                y: by * s,
                side: s,
            };
            used += area;
        }
        Atlas {
            side,
            layers: used.div_ceil(layer_area) as u32,
            slots,
        }
    }

    /// Texels the layers take.
    pub fn texels(&self) -> u64 {
        u64::from(self.side) * u64::from(self.side) * u64::from(self.layers)
    }
}

/// Halves the largest of `sides` (the last of equal ones) until maps of `sides`, packed, take at
/// most `budget` texels, or every side is `floor`; returns how many were halved. Deterministic,
/// so the same lights get the same sides on every frame and every node.
pub fn fit_budget(sides: &mut [u32], budget: u64, floor: u32) -> u32 {
    let mut halved = 0;
    while Atlas::pack(sides).texels() > budget {
        let Some((i, _)) = sides
            .iter()
            .enumerate()
            .filter(|(_, s)| **s > floor)
            .max_by_key(|(i, s)| (**s, *i))
        else {
            break;
        };
        sides[i] /= 2;
        halved += 1;
    }
    halved
}

#[cfg(test)]
mod tests {
    use super::*;

    fn overlap(a: Slot, b: Slot) -> bool {
        a.layer == b.layer
            && a.x < b.x + b.side
            && b.x < a.x + a.side
            && a.y < b.y + b.side
            && b.y < a.y + a.side
    }

    #[test]
    fn squares_pack_without_overlap_or_waste() {
        let sides = [512, 2048, 256, 1024, 512, 256, 256, 2048, 1024, 128];
        let a = Atlas::pack(&sides);
        assert_eq!(a.side, 2048);
        let area: u64 = sides.iter().map(|&s| u64::from(s) * u64::from(s)).sum();
        assert_eq!(a.layers as u64, area.div_ceil(2048 * 2048));
        for (i, s) in a.slots.iter().enumerate() {
            assert_eq!(s.side, sides[i]);
            assert!(s.x + s.side <= a.side && s.y + s.side <= a.side, "{s:?}");
            assert!(s.layer < a.layers);
            for t in &a.slots[i + 1..] {
                assert!(!overlap(*s, *t), "{s:?} overlaps {t:?}");
            }
        }
        // Equal sides keep their order: the first 2048 takes layer 0.
        assert_eq!(a.slots[1].layer, 0);
        assert_eq!(a.slots[7].layer, 1);
    }

    #[test]
    fn one_size_is_one_map_per_layer() {
        let a = Atlas::pack(&[512; 5]);
        assert_eq!((a.side, a.layers), (512, 5));
        for (i, s) in a.slots.iter().enumerate() {
            assert_eq!(
                *s,
                Slot {
                    layer: i as u32,
                    x: 0,
                    y: 0,
                    side: 512
                }
            );
        }
        assert_eq!(Atlas::pack(&[]), Atlas::default());
        // Sides that are not powers of two get a layer each, in the largest's side.
        let a = Atlas::pack(&[600, 300]);
        assert_eq!((a.side, a.layers), (600, 2));
        assert_eq!((a.slots[1].layer, a.slots[1].side), (1, 300));
    }

    #[test]
    fn the_budget_halves_the_largest_first() {
        let mut sides = vec![2048, 512, 2048, 1024];
        let budget = 2 * 2048 * 2048;
        let halved = fit_budget(&mut sides, budget, 256);
        assert!(Atlas::pack(&sides).texels() <= budget);
        assert_eq!(sides, [2048, 512, 1024, 1024]);
        assert_eq!(halved, 1);
        // A budget below the floor stops at the floor.
        let mut tiny = vec![1024, 1024];
        fit_budget(&mut tiny, 1, 256);
        assert_eq!(tiny, [256, 256]);
    }
}
