//! VTK XML unstructured grid (`.vtu`) writer: tetrahedra (VTK cell type 10), binary data
//! inline as base64 with a UInt64 byte-count header — the layout ParaView and meshio read.

/// One data array: a name, components per tuple, and values.
pub enum DataArray<'a> {
    /// Float32 values, `components` per tuple.
    F32(&'a str, usize, &'a [f32]),
    /// Int32 values, one per tuple.
    I32(&'a str, &'a [i32]),
}

/// How every file this module writes begins (its first two lines, less the second's
/// newline): what [`super::remove_earlier_outputs`] knows palpate's `.vtu` files by.
pub const PROLOGUE: &str = "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">";

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// Standard base64 with padding.
pub fn base64(data: &[u8]) -> String {
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for chunk in data.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(B64[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn encode(bytes: &[u8]) -> String {
    let mut block = (bytes.len() as u64).to_le_bytes().to_vec();
    block.extend_from_slice(bytes);
    base64(&block)
}

fn array_xml(a: &DataArray) -> String {
    match a {
        DataArray::F32(name, comps, v) => format!(
            "        <DataArray type=\"Float32\" Name=\"{name}\" NumberOfComponents=\"{comps}\" format=\"binary\">{}</DataArray>\n",
            encode(bytemuck::cast_slice(v))
        ),
        DataArray::I32(name, v) => format!(
            "        <DataArray type=\"Int32\" Name=\"{name}\" format=\"binary\">{}</DataArray>\n",
            encode(bytemuck::cast_slice(v))
        ),
    }
}

/// A `.vtu` document for points (packed xyz) and tets with point and cell data.
pub fn vtu(
    points: &[f32],
    tets: &[[u32; 4]],
    point_data: &[DataArray],
    cell_data: &[DataArray],
) -> String {
    let conn: Vec<i64> = tets.iter().flatten().map(|&i| i as i64).collect();
    let offsets: Vec<i64> = (1..=tets.len() as i64).map(|k| 4 * k).collect();
    document(points, &conn, &offsets, 10, point_data, cell_data)
}

/// A `.vtu` document of a point cloud: one VTK_VERTEX cell (type 1) per point.
pub fn vtu_points(points: &[f32], point_data: &[DataArray]) -> String {
    let n = points.len() as i64 / 3;
    let conn: Vec<i64> = (0..n).collect();
    let offsets: Vec<i64> = (1..=n).collect();
    document(points, &conn, &offsets, 1, point_data, &[])
}

fn document(
    points: &[f32],
    conn: &[i64],
    offsets: &[i64],
    cell_type: u8,
    point_data: &[DataArray],
    cell_data: &[DataArray],
) -> String {
    let n = points.len() / 3;
    let cells = offsets.len();
    let mut s = String::new();
    s.push_str(PROLOGUE);
    // Marked as palpate's, so that a later run into the folder can tell a killed run's file
    // from another tool's (whose uncompressed VTK 9 files begin as these do).
    s.push_str("\n  ");
    s.push_str(super::PVD_MARK);
    s.push_str("\n  <UnstructuredGrid>\n");
    s.push_str(&format!(
        "    <Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{cells}\">\n"
    ));
    s.push_str("      <PointData>\n");
    for a in point_data {
        s.push_str(&array_xml(a));
    }
    s.push_str("      </PointData>\n      <CellData>\n");
    for a in cell_data {
        s.push_str(&array_xml(a));
    }
    s.push_str("      </CellData>\n      <Points>\n");
    s.push_str(&format!(
        "        <DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"binary\">{}</DataArray>\n",
        encode(bytemuck::cast_slice(points))
    ));
    s.push_str("      </Points>\n      <Cells>\n");
    let types = vec![cell_type; cells];
    s.push_str(&format!(
        "        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"binary\">{}</DataArray>\n",
        encode(bytemuck::cast_slice(conn))
    ));
    s.push_str(&format!(
        "        <DataArray type=\"Int64\" Name=\"offsets\" format=\"binary\">{}</DataArray>\n",
        encode(bytemuck::cast_slice(offsets))
    ));
    s.push_str(&format!(
        "        <DataArray type=\"UInt8\" Name=\"types\" format=\"binary\">{}</DataArray>\n",
        encode(&types)
    ));
    s.push_str("      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    s
}
