//! `lightfold defaults`'s text: the defaults and every limit, named.

#[test]
fn the_limits_are_printed() {
    let t = lightfold_scene::defaults::describe();
    for want in [
        "800x600",
        "at most 8192 per side and 16777216 pixels (4096x4096)",
        "at most 4096²",
        "samples/area light",
        "N·width x N·height within the image limit",
        "at most 16384 per scene",
        "at most 10000000 per scene",
        "at most 1024 MiB of files read",
        "at most 16 MiB",
    ] {
        assert!(t.contains(want), "{want:?} missing from\n{t}");
    }
}
