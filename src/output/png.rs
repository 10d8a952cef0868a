//! A minimal PNG writer (RGB, deflated with `miniz_oxide`, already here for VTU) and a small
//! raster canvas with lines, dots and a 3×5 pixel font — enough for the log-log
//! error-versus-run-time plot of `palpate bench accuracy`.

/// An RGB image.
pub struct Canvas {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Pixels, row-major RGB.
    pub pixels: Vec<[u8; 3]>,
}

/// 3×5 glyphs: each row is 3 bits, most significant = left.
const GLYPHS: &[(char, [u8; 5])] = &[
    ('0', [7, 5, 5, 5, 7]),
    ('1', [2, 6, 2, 2, 7]),
    ('2', [7, 1, 7, 4, 7]),
    ('3', [7, 1, 7, 1, 7]),
    ('4', [5, 5, 7, 1, 1]),
    ('5', [7, 4, 7, 1, 7]),
    ('6', [7, 4, 7, 5, 7]),
    ('7', [7, 1, 1, 1, 1]),
    ('8', [7, 5, 7, 5, 7]),
    ('9', [7, 5, 7, 1, 7]),
    ('.', [0, 0, 0, 0, 2]),
    ('-', [0, 0, 7, 0, 0]),
    ('+', [0, 2, 7, 2, 0]),
    ('[', [6, 4, 4, 4, 6]),
    (']', [3, 1, 1, 1, 3]),
    ('(', [2, 4, 4, 4, 2]),
    (')', [2, 1, 1, 1, 2]),
    ('/', [1, 1, 2, 4, 4]),
    ('=', [0, 7, 0, 7, 0]),
    (',', [0, 0, 0, 2, 4]),
    (':', [0, 2, 0, 2, 0]),
    ('a', [0, 7, 1, 7, 7]),
    ('b', [4, 4, 7, 5, 7]),
    ('c', [0, 7, 4, 4, 7]),
    ('d', [1, 1, 7, 5, 7]),
    ('e', [7, 5, 7, 4, 7]),
    ('f', [3, 4, 6, 4, 4]),
    ('g', [7, 5, 7, 1, 7]),
    ('h', [4, 4, 7, 5, 5]),
    ('i', [2, 0, 2, 2, 2]),
    ('k', [4, 5, 6, 5, 5]),
    ('l', [2, 2, 2, 2, 3]),
    ('m', [0, 7, 7, 5, 5]),
    ('n', [0, 6, 5, 5, 5]),
    ('o', [0, 7, 5, 5, 7]),
    ('p', [7, 5, 7, 4, 4]),
    ('r', [0, 7, 4, 4, 4]),
    ('s', [7, 4, 7, 1, 7]),
    ('t', [4, 7, 4, 4, 3]),
    ('u', [0, 5, 5, 5, 7]),
    ('v', [0, 5, 5, 5, 2]),
    ('w', [0, 5, 5, 7, 7]),
    ('x', [0, 5, 2, 2, 5]),
    ('y', [5, 5, 7, 1, 7]),
    ('z', [7, 1, 2, 4, 7]),
];

impl Canvas {
    /// A white canvas.
    pub fn new(width: usize, height: usize) -> Canvas {
        Canvas {
            width,
            height,
            pixels: vec![[255; 3]; width * height],
        }
    }

    /// Set a pixel (ignored outside).
    pub fn put(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.pixels[y as usize * self.width + x as usize] = c;
        }
    }

    /// A line from (x0, y0) to (x1, y1), `thick` px wide.
    pub fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), c: [u8; 3], thick: i64) {
        let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
        for k in 0..=n {
            let t = k as f64 / n as f64;
            let (x, y) = (x0 + t * (x1 - x0), y0 + t * (y1 - y0));
            for dx in 0..thick {
                for dy in 0..thick {
                    self.put(x as i64 + dx, y as i64 + dy, c);
                }
            }
        }
    }

    /// A filled square dot of half-size `r` centred at (x, y).
    pub fn dot(&mut self, x: f64, y: f64, r: i64, c: [u8; 3]) {
        for dx in -r..=r {
            for dy in -r..=r {
                self.put(x as i64 + dx, y as i64 + dy, c);
            }
        }
    }

    /// Text with the 3×5 font scaled by `scale`, top-left at (x, y); unknown characters are blank.
    pub fn text(&mut self, x: i64, y: i64, s: &str, scale: i64, c: [u8; 3]) {
        for (i, ch) in s.chars().enumerate() {
            let ch = ch.to_ascii_lowercase();
            let Some((_, rows)) = GLYPHS.iter().find(|(g, _)| *g == ch) else {
                continue;
            };
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..3 {
                    if bits >> (2 - col) & 1 == 1 {
                        for sx in 0..scale {
                            for sy in 0..scale {
                                self.put(
                                    x + (i as i64 * 4 + col) * scale + sx,
                                    y + r as i64 * scale + sy,
                                    c,
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    /// Encode as PNG.
    pub fn png(&self) -> Vec<u8> {
        let mut raw = Vec::with_capacity(self.height * (1 + 3 * self.width));
        for row in self.pixels.chunks(self.width) {
            raw.push(0);
            for p in row {
                raw.extend_from_slice(p);
            }
        }
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(&(self.width as u32).to_be_bytes());
        ihdr.extend_from_slice(&(self.height as u32).to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
        chunk(&mut out, b"IHDR", &ihdr);
        // Level 6: a plot (mostly flat background) shrinks ~100× (1.6 MB stored → ~15 kB).
        chunk(
            &mut out,
            b"IDAT",
            &miniz_oxide::deflate::compress_to_vec_zlib(&raw, 6),
        );
        chunk(&mut out, b"IEND", &[]);
        out
    }
}

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// CRC-32 (IEEE), as PNG chunks need.
pub fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A point of a scatter plot: x, y (both > 0, plotted on log axes) and a series index.
#[derive(Clone, Copy, Debug)]
pub struct PlotPoint {
    /// x value.
    pub x: f64,
    /// y value.
    pub y: f64,
    /// Series (colour) index.
    pub series: usize,
}

const COLOURS: [[u8; 3]; 6] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
];

/// Log-log scatter plot with a highlighted polyline (`front`, indices into `points`), axis
/// decades labelled, series legend.
pub fn loglog_plot(
    points: &[PlotPoint],
    front: &[usize],
    x_label: &str,
    y_label: &str,
    legend: &[String],
) -> Canvas {
    let (w, h) = (900usize, 600usize);
    let mut c = Canvas::new(w, h);
    let (l, r, t, b) = (90.0, 860.0, 40.0, 520.0);
    let decade = |v: f64, up: bool| {
        if up {
            v.log10().ceil()
        } else {
            v.log10().floor()
        }
    };
    let xs = points.iter().map(|p| p.x);
    let ys = points.iter().map(|p| p.y);
    let (x0, x1) = (
        decade(xs.clone().fold(f64::INFINITY, f64::min), false),
        decade(xs.fold(0.0, f64::max), true).max(decade(1e-300, false)),
    );
    let (y0, y1) = (
        decade(ys.clone().fold(f64::INFINITY, f64::min), false),
        decade(ys.fold(0.0, f64::max), true),
    );
    let (x1, y1) = (
        if x1 <= x0 { x0 + 1.0 } else { x1 },
        if y1 <= y0 { y0 + 1.0 } else { y1 },
    );
    let px = |x: f64| l + (x.log10() - x0) / (x1 - x0) * (r - l);
    let py = |y: f64| b - (y.log10() - y0) / (y1 - y0) * (b - t);
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    for d in x0 as i64..=x1 as i64 {
        let x = px(10f64.powi(d as i32));
        c.line((x, t), (x, b), grey, 1);
        c.text(x as i64 - 12, b as i64 + 10, &format!("1e{d}"), 2, black);
    }
    for d in y0 as i64..=y1 as i64 {
        let y = py(10f64.powi(d as i32));
        c.line((l, y), (r, y), grey, 1);
        c.text(l as i64 - 60, y as i64 - 5, &format!("1e{d}"), 2, black);
    }
    c.line((l, b), (r, b), black, 2);
    c.line((l, t), (l, b), black, 2);
    c.text((l + r) as i64 / 2 - 60, b as i64 + 40, x_label, 3, black);
    c.text(10, 12, y_label, 3, black);
    for w2 in front.windows(2) {
        let (p, q) = (points[w2[0]], points[w2[1]]);
        c.line((px(p.x), py(p.y)), (px(q.x), py(q.y)), black, 2);
    }
    for p in points {
        c.dot(px(p.x), py(p.y), 4, COLOURS[p.series % COLOURS.len()]);
    }
    for (i, name) in legend.iter().enumerate() {
        let y = t as i64 + 10 + 22 * i as i64;
        c.dot(r - 170.0, y as f64 + 5.0, 4, COLOURS[i % COLOURS.len()]);
        c.text(r as i64 - 155, y, name, 2, black);
    }
    c
}

/// Indices of the Pareto-optimal points (no other point has both smaller x and smaller y),
/// sorted by x.
pub fn pareto_front(points: &[PlotPoint]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len()).collect();
    idx.sort_by(|&a, &b| {
        points[a]
            .x
            .total_cmp(&points[b].x)
            .then(points[a].y.total_cmp(&points[b].y))
    });
    let mut front = Vec::new();
    let mut best = f64::INFINITY;
    for i in idx {
        if points[i].y < best {
            best = points[i].y;
            front.push(i);
        }
    }
    front
}

#[cfg(test)]
mod tests {
    use super::Canvas;

    /// The IDAT stream inflates back to the filtered rows, and a plot-like image (flat
    /// background, a line, text) comes out far smaller than its raw pixels.
    #[test]
    fn png_pixels_inflate_back_and_compress() {
        let mut c = Canvas::new(400, 300);
        for x in 0..400 {
            c.put(x, 150 + x / 10, [200, 0, 0]);
        }
        c.text(10, 10, "error vs run time", 2, [0, 0, 0]);
        let png = c.png();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        // Chunks: IHDR (13 bytes) at 8, then IDAT.
        let at = 8 + 12 + 13;
        let len = u32::from_be_bytes(png[at..at + 4].try_into().unwrap()) as usize;
        assert_eq!(&png[at + 4..at + 8], b"IDAT");
        let data = &png[at + 8..at + 8 + len];
        let crc = u32::from_be_bytes(png[at + 8 + len..at + 12 + len].try_into().unwrap());
        assert_eq!(crc, super::crc32(&png[at + 4..at + 8 + len]));
        let raw = miniz_oxide::inflate::decompress_to_vec_zlib(data).unwrap();
        assert_eq!(raw.len(), 300 * (1 + 3 * 400));
        for (y, row) in raw.chunks(1 + 3 * 400).enumerate() {
            assert_eq!(row[0], 0, "row {y}: filter type");
            for (x, px) in row[1..].chunks(3).enumerate() {
                assert_eq!(px, &c.pixels[y * 400 + x][..], "pixel ({x}, {y})");
            }
        }
        assert!(
            png.len() * 20 < raw.len(),
            "{} bytes from {}",
            png.len(),
            raw.len()
        );
    }
}
