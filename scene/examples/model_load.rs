//! Load time and memory of the model formats on one model (`docs/scenes.md` § Loading cost).
//!
//! ```sh
//! cargo run --release -p lightfold-scene --example model_load -- write /tmp/models 1000000
//! /usr/bin/time -v target/release/examples/model_load load /tmp/models/grid.obj
//! ```
//!
//! `write DIR N` writes a rippled grid of about N triangles (positions, normals, texture
//! coordinates, 32-bit indices) as `grid.glb`, `grid.obj` (with `grid.mtl`), `grid.ply` (binary
//! little-endian), `grid-ascii.ply` and `grid.usda` (a USD mesh of triangles; usd-core's
//! `Sdf.Layer.FindOrOpen("grid.usda").Export("grid.usdc")` makes the binary form). `load PATH` loads one through `lightfold_scene::load` (as
//! `--scene PATH` does: completed with a camera, light and ground) and prints its triangles and
//! the seconds the load took; `/usr/bin/time -v` adds the peak resident memory of the process.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    match args.get(1).map(String::as_str) {
        Some("write") if args.len() == 4 => write(Path::new(&args[2]), args[3].parse()?),
        Some("load") if args.len() == 3 => {
            let start = std::time::Instant::now();
            let scene = lightfold_scene::load(&args[2])?;
            let seconds = start.elapsed().as_secs_f64();
            println!(
                "{}: {} triangles in {} meshes, {} materials, loaded in {seconds:.3} s",
                args[2],
                scene.triangle_count(),
                scene.meshes.len(),
                scene.materials.len()
            );
            Ok(())
        }
        _ => Err("usage: model_load write DIR TRIANGLES | model_load load PATH".into()),
    }
}

/// A `side × side` grid of vertices over [-1, 1]², rippled in y.
struct Grid {
    side: u32,
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<u32>,
}

fn grid(triangles: u64) -> Grid {
    let quads = ((triangles as f64 / 2.0).sqrt().ceil() as u32).max(1);
    let side = quads + 1;
    let mut g = Grid {
        side,
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        indices: Vec::new(),
    };
    for j in 0..side {
        for i in 0..side {
            let (u, v) = (i as f32 / quads as f32, j as f32 / quads as f32);
            let (x, z) = (2.0 * u - 1.0, 2.0 * v - 1.0);
            let (k, a) = (12.0f32, 0.05f32);
            let y = a * (k * x).sin() * (k * z).cos();
            // The normal of y(x, z): (−∂y/∂x, 1, −∂y/∂z), normalised.
            let (dx, dz) = (
                a * k * (k * x).cos() * (k * z).cos(),
                -a * k * (k * x).sin() * (k * z).sin(),
            );
            let l = (dx * dx + 1.0 + dz * dz).sqrt();
            g.positions.push([x, y, z]);
            g.normals.push([-dx / l, 1.0 / l, -dz / l]);
            g.uvs.push([u, v]);
        }
    }
    for j in 0..quads {
        for i in 0..quads {
            let a = j * side + i;
            let (b, c, d) = (a + 1, a + side, a + side + 1);
            // Counter-clockwise seen from +y.
            g.indices.extend_from_slice(&[a, c, b, b, c, d]);
        }
    }
    g
}

fn write(dir: &Path, triangles: u64) -> Result<(), Box<dyn std::error::Error>> {
    std::fs::create_dir_all(dir)?;
    let g = grid(triangles);
    println!(
        "{} × {} vertices, {} triangles",
        g.side,
        g.side,
        g.indices.len() / 3
    );
    write_glb(&g, &dir.join("grid.glb"))?;
    write_obj(&g, dir)?;
    write_ply(&g, &dir.join("grid.ply"), false)?;
    write_ply(&g, &dir.join("grid-ascii.ply"), true)?;
    write_usda(&g, &dir.join("grid.usda"))?;
    for f in [
        "grid.glb",
        "grid.obj",
        "grid.ply",
        "grid-ascii.ply",
        "grid.usda",
    ] {
        println!("{f}: {} bytes", std::fs::metadata(dir.join(f))?.len());
    }
    Ok(())
}

fn write_glb(g: &Grid, path: &Path) -> std::io::Result<()> {
    let n = g.positions.len();
    let mut bin = Vec::new();
    for p in g.positions.iter().chain(&g.normals) {
        p.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for t in &g.uvs {
        t.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for i in &g.indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let (p, nrm, uv, idx) = (12 * n, 12 * n, 8 * n, 4 * g.indices.len());
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2}},"indices":3,"material":0}}]}}],
"materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[0.8,0.8,0.8,1],"metallicFactor":0,"roughnessFactor":1}}}}],
"buffers":[{{"byteLength":{len}}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{p}}},{{"buffer":0,"byteOffset":{o1},"byteLength":{nrm}}},
{{"buffer":0,"byteOffset":{o2},"byteLength":{uv}}},{{"buffer":0,"byteOffset":{o3},"byteLength":{idx}}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3","min":[-1,-0.05,-1],"max":[1,0.05,1]}},
{{"bufferView":1,"componentType":5126,"count":{n},"type":"VEC3"}},
{{"bufferView":2,"componentType":5126,"count":{n},"type":"VEC2"}},
{{"bufferView":3,"componentType":5125,"count":{k},"type":"SCALAR"}}]}}"#,
        len = bin.len(),
        o1 = p,
        o2 = p + nrm,
        o3 = p + nrm + uv,
        k = g.indices.len(),
    );
    let mut json = json.into_bytes();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let total = 12 + 8 + json.len() + 8 + bin.len();
    out.write_all(b"glTF")?;
    out.write_all(&2u32.to_le_bytes())?;
    out.write_all(&(total as u32).to_le_bytes())?;
    out.write_all(&(json.len() as u32).to_le_bytes())?;
    out.write_all(b"JSON")?;
    out.write_all(&json)?;
    out.write_all(&(bin.len() as u32).to_le_bytes())?;
    out.write_all(b"BIN\0")?;
    out.write_all(&bin)?;
    out.flush()
}

fn write_obj(g: &Grid, dir: &Path) -> std::io::Result<()> {
    std::fs::write(dir.join("grid.mtl"), "newmtl grey\nKd 0.8 0.8 0.8\n")?;
    let mut out = std::io::BufWriter::new(std::fs::File::create(dir.join("grid.obj"))?);
    let mut line = String::new();
    writeln!(out, "mtllib grid.mtl\no grid\nusemtl grey")?;
    for [x, y, z] in &g.positions {
        line.clear();
        writeln!(line, "v {x} {y} {z}").unwrap();
        out.write_all(line.as_bytes())?;
    }
    for [u, v] in &g.uvs {
        line.clear();
        writeln!(line, "vt {u} {}", 1.0 - v).unwrap();
        out.write_all(line.as_bytes())?;
    }
    for [x, y, z] in &g.normals {
        line.clear();
        writeln!(line, "vn {x} {y} {z}").unwrap();
        out.write_all(line.as_bytes())?;
    }
    for t in g.indices.chunks_exact(3) {
        let [a, b, c] = [t[0] + 1, t[1] + 1, t[2] + 1];
        line.clear();
        writeln!(line, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}").unwrap();
        out.write_all(line.as_bytes())?;
    }
    out.flush()
}

fn write_ply(g: &Grid, path: &Path, ascii: bool) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let format = if ascii {
        "ascii"
    } else {
        "binary_little_endian"
    };
    write!(
        out,
        "ply\nformat {format} 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        g.positions.len(),
        g.indices.len() / 3
    )?;
    let mut line = String::new();
    for (p, n) in g.positions.iter().zip(&g.normals) {
        if ascii {
            line.clear();
            writeln!(
                line,
                "{} {} {} {} {} {}",
                p[0], p[1], p[2], n[0], n[1], n[2]
            )
            .unwrap();
            out.write_all(line.as_bytes())?;
        } else {
            for c in p.iter().chain(n) {
                out.write_all(&c.to_le_bytes())?;
            }
        }
    }
    for t in g.indices.chunks_exact(3) {
        if ascii {
            line.clear();
            writeln!(line, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
            out.write_all(line.as_bytes())?;
        } else {
            out.write_all(&[3])?;
            for i in t {
                out.write_all(&(*i as i32).to_le_bytes())?;
            }
        }
    }
    out.flush()
}

fn write_usda(g: &Grid, path: &Path) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        out,
        "#usda 1.0\n(\n    defaultPrim = \"grid\"\n    metersPerUnit = 1\n    upAxis = \"Y\"\n)\n\n\
         def Mesh \"grid\"\n{{\n    uniform token subdivisionScheme = \"none\"\n    \
         color3f[] primvars:displayColor = [(0.8, 0.8, 0.8)]"
    )?;
    let mut line = String::new();
    let mut array = |name: &str, items: &mut dyn Iterator<Item = String>| -> std::io::Result<()> {
        write!(out, "    {name} = [")?;
        for (k, item) in items.enumerate() {
            line.clear();
            if k > 0 {
                line.push_str(", ");
            }
            line.push_str(&item);
            out.write_all(line.as_bytes())?;
        }
        writeln!(out, "]")
    };
    array(
        "point3f[] points",
        &mut g
            .positions
            .iter()
            .map(|p| format!("({}, {}, {})", p[0], p[1], p[2])),
    )?;
    array(
        "normal3f[] normals",
        &mut g
            .normals
            .iter()
            .map(|n| format!("({}, {}, {})", n[0], n[1], n[2])),
    )?;
    array(
        "texCoord2f[] primvars:st",
        &mut g.uvs.iter().map(|t| format!("({}, {})", t[0], t[1])),
    )?;
    array(
        "int[] faceVertexCounts",
        &mut (0..g.indices.len() / 3).map(|_| "3".to_string()),
    )?;
    array(
        "int[] faceVertexIndices",
        &mut g.indices.iter().map(|i| i.to_string()),
    )?;
    writeln!(out, "}}")?;
    out.flush()
}
