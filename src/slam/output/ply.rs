//! The semantic map as PLY (binary little-endian or ASCII): real colour as `red green
//! blue`, semantic colour as `sem_red sem_green sem_blue`, and `label`; MeshLab,
//! CloudCompare and Open3D read it.

use crate::classes;
use crate::error::{Error, Result};
use crate::slam::mapping::semantic_map::MapPoint;
use nalgebra::Point3;
use std::io::{BufRead, Read, Write};
use std::path::Path;

const PLY_PROPS: [(&str, &str); 10] = [
    ("float", "x"),
    ("float", "y"),
    ("float", "z"),
    ("uchar", "red"),
    ("uchar", "green"),
    ("uchar", "blue"),
    ("uchar", "sem_red"),
    ("uchar", "sem_green"),
    ("uchar", "sem_blue"),
    ("uchar", "label"),
];

/// Writes map points as PLY, atomically: binary little-endian, or ASCII.
pub(crate) fn write_ply(path: impl AsRef<Path>, points: &[MapPoint], ascii: bool) -> Result<()> {
    crate::io::write_atomic_with(path, |w| {
        let format = if ascii {
            "ascii"
        } else {
            "binary_little_endian"
        };
        writeln!(w, "ply\nformat {format} 1.0")?;
        writeln!(
            w,
            "comment sdf-slam semantic map: real colour red/green/blue, NYU40 class colour sem_*, label 0-39 (255 = none)"
        )?;
        writeln!(w, "element vertex {}", points.len())?;
        for (t, n) in PLY_PROPS {
            writeln!(w, "property {t} {n}")?;
        }
        writeln!(w, "end_header")?;
        for p in points {
            let s = classes::colorize(p.label);
            if ascii {
                writeln!(
                    w,
                    "{} {} {} {} {} {} {} {} {} {}",
                    p.position.x,
                    p.position.y,
                    p.position.z,
                    p.rgb[0],
                    p.rgb[1],
                    p.rgb[2],
                    s[0],
                    s[1],
                    s[2],
                    p.label
                )?;
            } else {
                for v in [p.position.x, p.position.y, p.position.z] {
                    w.write_all(&v.to_le_bytes())?;
                }
                w.write_all(&p.rgb)?;
                w.write_all(&s)?;
                w.write_all(&[p.label])?;
            }
        }
        Ok(())
    })
}

/// Reads a PLY vertex list with (at least) `x y z` and optionally `red green
/// blue` and `label` properties, binary little-endian or ASCII.
pub fn read_ply(path: impl AsRef<Path>) -> Result<Vec<MapPoint>> {
    let path = path.as_ref();
    let bad = |m: String| Error::invalid(path, m);
    let (file, _) = crate::io::open_regular(path, "a PLY file")?;
    let mut r = std::io::BufReader::new(file);
    let mut line = String::new();
    let mut next = |r: &mut std::io::BufReader<std::fs::File>| -> Result<String> {
        line.clear();
        let n = r.read_line(&mut line).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            return Err(Error::invalid(path, "PLY header ends early"));
        }
        Ok(line.trim().to_string())
    };
    if next(&mut r)? != "ply" {
        return Err(bad("not a PLY file".into()));
    }
    let (mut binary, mut count, mut props) = (None, None, Vec::<(String, String)>::new());
    let mut in_vertex = false;
    loop {
        let l = next(&mut r)?;
        let f: Vec<&str> = l.split_whitespace().collect();
        match f.as_slice() {
            ["end_header"] => break,
            ["format", "binary_little_endian", _] => binary = Some(true),
            ["format", "ascii", _] => binary = Some(false),
            ["format", other, _] => return Err(bad(format!("unsupported PLY format {other}"))),
            ["element", "vertex", n] => {
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| bad(format!("bad vertex count '{n}'")))?,
                );
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", t, n] if in_vertex => props.push((t.to_string(), n.to_string())),
            _ => {}
        }
    }
    let binary = binary.ok_or_else(|| bad("PLY header has no format line".into()))?;
    let count = count.ok_or_else(|| bad("PLY has no vertex element".into()))?;
    let size = |t: &str| -> Result<usize> {
        match t {
            "char" | "uchar" | "int8" | "uint8" => Ok(1),
            "short" | "ushort" | "int16" | "uint16" => Ok(2),
            "int" | "uint" | "float" | "int32" | "uint32" | "float32" => Ok(4),
            "double" | "float64" => Ok(8),
            _ => Err(Error::invalid(
                path,
                format!("unsupported PLY property type {t}"),
            )),
        }
    };
    let sizes: Vec<usize> = props.iter().map(|p| size(&p.0)).collect::<Result<_>>()?;
    let find = |name: &str| props.iter().position(|p| p.1 == name);
    let (Some(ix), Some(iy), Some(iz)) = (find("x"), find("y"), find("z")) else {
        return Err(bad("PLY vertices have no x y z".into()));
    };
    let colour = [find("red"), find("green"), find("blue")];
    let label = find("label");
    let mut values = vec![0f64; props.len()];
    let mut out = Vec::with_capacity(count.min(1 << 24));
    let mut text = String::new();
    if !binary {
        r.read_to_string(&mut text)
            .map_err(|e| Error::io(path, e))?;
    }
    let mut tokens = text.split_whitespace();
    let record = sizes.iter().sum::<usize>();
    let mut buf = vec![0u8; record];
    for k in 0..count {
        if binary {
            r.read_exact(&mut buf)
                .map_err(|_| bad(format!("PLY body ends at vertex {k} of {count}")))?;
            let mut o = 0;
            for (v, (p, s)) in values.iter_mut().zip(props.iter().zip(&sizes)) {
                let b = &buf[o..o + s];
                *v = match p.0.as_str() {
                    "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    "double" | "float64" => {
                        f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                    }
                    "uchar" | "uint8" => b[0] as f64,
                    "char" | "int8" => b[0] as i8 as f64,
                    "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
                    "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
                    "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                };
                o += s;
            }
        } else {
            for v in values.iter_mut() {
                let t = tokens
                    .next()
                    .ok_or_else(|| bad(format!("PLY body ends at vertex {k} of {count}")))?;
                *v = t
                    .parse()
                    .map_err(|_| bad(format!("vertex {k}: '{t}' is not a number")))?;
            }
        }
        let byte = |i: Option<usize>| i.map_or(0, |i| values[i].clamp(0.0, 255.0) as u8);
        out.push(MapPoint {
            position: Point3::new(values[ix] as f32, values[iy] as f32, values[iz] as f32),
            rgb: colour.map(byte),
            label: label.map_or(classes::VOID, |i| values[i].clamp(0.0, 255.0) as u8),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ply_round_trip_binary_and_ascii() {
        let dir = std::env::temp_dir().join(format!("sdf_ply_{}", std::process::id()));
        let pts: Vec<MapPoint> = (0..37)
            .map(|i| MapPoint {
                position: Point3::new(i as f32 * 0.5, -1.25, 3.0 + i as f32),
                rgb: [i as u8, 200, 7],
                label: if i % 5 == 0 {
                    classes::VOID
                } else {
                    (i % 40) as u8
                },
            })
            .collect();
        for ascii in [false, true] {
            let p = dir.join(if ascii { "a.ply" } else { "b.ply" });
            write_ply(&p, &pts, ascii).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            let header_end = bytes
                .windows(11)
                .position(|w| w == b"end_header\n")
                .unwrap()
                + 11;
            let header = std::str::from_utf8(&bytes[..header_end]).unwrap();
            assert!(header.contains("element vertex 37"));
            assert!(
                header.contains("property uchar sem_red")
                    && header.contains("property uchar label")
            );
            if !ascii {
                assert!(header.contains("binary_little_endian"));
                assert_eq!(bytes.len() - header_end, 37 * 19);
                // First vertex, by hand: x = 0.0, y = -1.25, z = 3.0, void label black.
                let body = &bytes[header_end..];
                assert_eq!(f32::from_le_bytes(body[4..8].try_into().unwrap()), -1.25);
                assert_eq!(&body[12..19], &[0, 200, 7, 0, 0, 0, 255]);
            }
            assert_eq!(read_ply(&p).unwrap(), pts);
        }
        let p = dir.join("trunc.ply");
        let mut bytes = std::fs::read(dir.join("b.ply")).unwrap();
        bytes.truncate(bytes.len() - 5);
        std::fs::write(&p, bytes).unwrap();
        assert!(read_ply(&p).unwrap_err().to_string().contains("vertex 36"));
        std::fs::remove_dir_all(dir).unwrap();
    }
}
