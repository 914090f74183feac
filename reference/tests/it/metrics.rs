//! Metrics and masks on synthetic images with known answers.

use lightfold_reference::masks::{dilate, penumbra, silhouettes};
use lightfold_reference::metrics::{MetricsError, compare, error_stats, flip_error_map_rgb8};
use lightfold_scene::Image;

fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 3]) -> Image {
    let mut img = Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            img.pixel_mut(x, y).copy_from_slice(&f(x, y));
        }
    }
    img
}

fn gradient(x: u32, y: u32) -> [f32; 3] {
    [x as f32 / 40.0, y as f32 / 30.0, 0.25]
}

#[test]
fn identical_images_have_zero_error() {
    let a = image(40, 30, gradient);
    let m = compare(&a, &a, 1.0, Some(&vec![true; 1200])).unwrap();
    assert_eq!(m.whole.rmse, 0.0);
    assert_eq!(m.whole.max_abs, 0.0);
    assert_eq!(m.whole.energy_bias, 0.0);
    assert!(m.whole.psnr.is_infinite());
    assert_eq!(m.flip, 0.0);
    assert_eq!(m.penumbra, Some(m.whole));
    assert!(m.to_string().contains("rmse"));
}

#[test]
fn known_offsets_give_known_figures() {
    let r = image(40, 30, |_, _| [0.5; 3]);
    let t = image(40, 30, |_, _| [0.6; 3]);
    let s = error_stats(&t, &r, 1.0, None).unwrap();
    assert!((s.rmse - 0.1).abs() < 1e-6);
    assert!((s.max_abs - 0.1).abs() < 1e-6);
    assert!((s.psnr - 20.0).abs() < 1e-4);
    assert!((s.energy_bias - 0.2).abs() < 1e-6);
    assert!((s.rel_mse - 0.01 / (0.25 + 0.01)).abs() < 1e-6);
    // Exposure scales the compared values: 2·0.1 error, PSNR 6 dB lower.
    let s2 = error_stats(&t, &r, 2.0, None).unwrap();
    assert!((s2.rmse - 0.2).abs() < 1e-6);
    assert!((s.psnr - s2.psnr - 20.0 * 2f64.log10()).abs() < 1e-4);
    assert!((s2.energy_bias - 0.2).abs() < 1e-6, "bias is exposure-free");
}

#[test]
fn non_finite_pixels_are_counted_and_left_out() {
    let r = image(4, 4, |_, _| [1.0; 3]);
    let mut t = r.clone();
    t.pixel_mut(1, 1)[0] = f32::NAN;
    t.pixel_mut(2, 3)[2] = f32::INFINITY;
    let s = error_stats(&t, &r, 1.0, None).unwrap();
    assert_eq!(s.non_finite, 2);
    assert_eq!(s.pixels, 14);
    assert_eq!(s.rmse, 0.0);
    let m = compare(&t, &r, 1.0, None).unwrap();
    assert!(
        !m.within_floor(&m),
        "non-finite pixels are never within the floor"
    );
}

#[test]
fn masks_select_pixels_and_bad_inputs_are_errors() {
    let r = image(10, 10, |_, _| [0.5; 3]);
    let t = image(10, 10, |x, _| if x < 5 { [0.5; 3] } else { [0.7; 3] });
    let left: Vec<bool> = (0..100).map(|i| i % 10 < 5).collect();
    let s = error_stats(&t, &r, 1.0, Some(&left)).unwrap();
    assert_eq!((s.pixels, s.rmse), (50, 0.0));
    let right: Vec<bool> = left.iter().map(|b| !b).collect();
    assert!((error_stats(&t, &r, 1.0, Some(&right)).unwrap().rmse - 0.2).abs() < 1e-6);
    assert!(matches!(
        error_stats(&t, &r, 1.0, Some(&left[..10])),
        Err(MetricsError::Mask {
            mask: 10,
            pixels: 100
        })
    ));
    let small = image(9, 10, |_, _| [0.5; 3]);
    assert!(matches!(
        compare(&small, &r, 1.0, None),
        Err(MetricsError::Size { .. })
    ));
    let grey = Image::new(10, 10, 1);
    assert!(matches!(
        compare(&grey, &r, 1.0, None),
        Err(MetricsError::Channels { .. })
    ));
}

#[test]
fn flip_sees_differences_and_renders_a_map() {
    let r = image(64, 48, gradient);
    let t = image(64, 48, |x, y| {
        if (x / 8 + y / 8) % 2 == 0 {
            gradient(x, y)
        } else {
            [0.9, 0.1, 0.1]
        }
    });
    let m = compare(&t, &r, 1.0, None).unwrap();
    assert!(m.flip > 0.05 && m.flip <= 1.0, "flip {}", m.flip);
    let near = image(64, 48, |x, y| gradient(x, y).map(|c| c * 1.001));
    let small = compare(&near, &r, 1.0, None).unwrap().flip;
    assert!(small < 0.2 * m.flip, "flip {small}");
    let map = flip_error_map_rgb8(&t, &r, 1.0).unwrap();
    assert_eq!(map.len(), 64 * 48 * 3);
}

#[test]
fn penumbra_is_the_partial_shadow_ratio() {
    let unocc = image(5, 1, |_, _| [1.0; 3]);
    let shadowed = image(5, 1, |x, _| [[0.0, 0.01, 0.5, 0.99, 1.0][x as usize]; 3]);
    assert_eq!(
        penumbra(&shadowed, &unocc),
        vec![false, false, true, false, false]
    );
    let black = image(5, 1, |_, _| [0.0; 3]);
    assert_eq!(penumbra(&black, &black), vec![false; 5]);
}

#[test]
fn silhouettes_find_depth_steps_not_slanted_planes() {
    let (w, h) = (20u32, 10u32);
    let mut depth = Image::new(w, h, 1);
    // A slanted plane: inverse depth affine in x.
    for y in 0..h {
        for x in 0..w {
            depth.data[(y * w + x) as usize] = 1.0 / (0.5 - 0.02 * x as f32);
        }
    }
    let cov = vec![true; (w * h) as usize];
    assert!(
        silhouettes(&depth, &cov, 1).iter().all(|&e| !e),
        "a plane has no silhouette"
    );
    // A step at x = 10 (an object in front).
    for y in 0..h {
        for x in 10..w {
            depth.data[(y * w + x) as usize] = 2.0;
        }
    }
    let edges = silhouettes(&depth, &cov, 0);
    assert!(edges[(5 * w + 10) as usize] || edges[(5 * w + 9) as usize]);
    assert!(!edges[(5 * w + 3) as usize] && !edges[(5 * w + 16) as usize]);
    // Coverage edges count too.
    let mut cov2 = cov.clone();
    cov2[(5 * w + 15) as usize] = false;
    assert!(silhouettes(&depth, &cov2, 0)[(5 * w + 14) as usize]);
}

#[test]
fn dilation_grows_a_square() {
    let mut m = vec![false; 49];
    m[3 * 7 + 3] = true;
    let d = dilate(&m, 7, 7, 2);
    assert_eq!(d.iter().filter(|&&b| b).count(), 25);
    assert!(d[7 + 1] && d[5 * 7 + 5] && !d[0]);
    assert_eq!(dilate(&m, 7, 7, 0), m);
}
