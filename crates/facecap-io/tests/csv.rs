#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
// The counting global allocator below needs `unsafe impl GlobalAlloc`.
#![allow(unsafe_code)]
//! Per-frame CSV writer and readers.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use facecap_core::landmarks::Landmarks68;
use facecap_core::Error;
use facecap_io::csv::{
    landmark_columns, landmark_values, mesh_columns, mesh_values, named_columns, parse_frame_csv, read_frame_csv,
    read_landmarks_csv, read_mesh_csv, FrameCsvWriter, FrameRow, MESH_POINTS, POSE_COLUMNS,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct CountingAlloc;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn allocs() -> u64 {
    ALLOCS.with(Cell::get)
}

fn all_columns() -> Vec<String> {
    let mut cols = landmark_columns();
    cols.extend(POSE_COLUMNS.iter().map(|s| s.to_string()));
    cols.extend(named_columns(&["jawOpen", "browInnerUp", "mouthSmile_L"]).unwrap());
    cols
}

fn random_landmarks(rng: &mut ChaCha8Rng) -> Landmarks68 {
    Landmarks68::from_fn(|_| (rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)))
}

#[test]
fn header_and_column_helpers() {
    let lc = landmark_columns();
    assert_eq!(lc.len(), 136);
    assert_eq!(lc[0], "x_0");
    assert_eq!(lc[67], "x_67");
    assert_eq!(lc[68], "y_0");
    assert_eq!(lc[135], "y_67");
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.csv");
    let w = FrameCsvWriter::create(&p, &all_columns()).unwrap();
    w.finish().unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    let header = text.lines().next().unwrap();
    assert!(header.starts_with("frame,timestamp,success,confidence,x_0,x_1,"));
    assert!(header.contains(",x_67,y_0,"));
    assert!(header.contains(",y_67,pose_Tx,pose_Ty,pose_Tz,pose_Rx,pose_Ry,pose_Rz,jawOpen,browInnerUp,mouthSmile_L"));
    assert_eq!(text.lines().count(), 1);
    for bad in ["", "a,b", "a\"", " x", "frame", "x\n"] {
        assert!(named_columns(&[bad]).is_err(), "{bad:?}");
    }
    assert!(named_columns(&["a", "a"]).is_err());
}

#[test]
fn round_trip_is_bit_exact_and_landmarks_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("out.csv");
    let cols = all_columns();
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let mut w = FrameCsvWriter::create(&p, &cols).unwrap();
    assert!(!p.exists(), "visible before finish");
    let mut expected = Vec::new();
    let mut lmv = [0.0f64; 136];
    for f in 0..50u64 {
        let success = f % 7 != 3;
        let lm = random_landmarks(&mut rng);
        landmark_values(success.then_some(&lm), &mut lmv);
        let mut values: Vec<f64> = lmv.to_vec();
        // awkward values: tiny, huge, negative zero, many digits
        values.extend([1e-300, 1.0e20, -0.0, 0.1 + 0.2, rng.random(), -rng.random::<f64>()]);
        values.extend((0..3).map(|_| rng.random_range(0.0..1.0)));
        let ts = f as f64 / 29.97;
        let conf = if success { rng.random() } else { 0.0 };
        w.write_row(&FrameRow {
            frame: f,
            timestamp: ts,
            success,
            confidence: conf,
            values: &values,
        })
        .unwrap();
        expected.push((f, ts, success, conf, values, lm));
    }
    assert_eq!(w.rows_written(), 50);
    w.finish().unwrap();

    let table = read_frame_csv(&p).unwrap();
    assert_eq!(table.columns, cols);
    assert_eq!(table.rows.len(), 50);
    for (row, (f, ts, s, c, values, _)) in table.rows.iter().zip(&expected) {
        assert_eq!(row.frame, *f);
        assert_eq!(row.timestamp.to_bits(), ts.to_bits());
        assert_eq!(row.success, *s);
        assert_eq!(row.confidence.to_bits(), c.to_bits());
        for (a, b) in row.values.iter().zip(values) {
            assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "{a} vs {b}");
        }
    }
    assert_eq!(table.column("jawOpen").unwrap().len(), 50);

    let lms = read_landmarks_csv(&p).unwrap();
    for (r, (_, _, s, _, _, lm)) in lms.iter().zip(&expected) {
        assert_eq!(r.success, *s);
        match &r.landmarks {
            Some(got) => assert_eq!(got, lm),
            None => assert!(!s),
        }
    }
    // Nothing but the CSV in the folder.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn dropping_without_finish_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.csv");
    {
        let mut w = FrameCsvWriter::create(&p, &["a"]).unwrap();
        w.write_row(&FrameRow {
            frame: 0,
            timestamp: 0.0,
            success: true,
            confidence: 1.0,
            values: &[1.0],
        })
        .unwrap();
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn write_row_validates() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = FrameCsvWriter::create(dir.path().join("v.csv"), &["a", "b"]).unwrap();
    let row = |ts: f64, conf: f64, values: &'static [f64]| FrameRow {
        frame: 1,
        timestamp: ts,
        success: true,
        confidence: conf,
        values,
    };
    assert!(matches!(
        w.write_row(&row(0.0, 1.0, &[1.0])),
        Err(Error::DimensionMismatch {
            expected: 2,
            got: 1,
            ..
        })
    ));
    assert!(matches!(
        w.write_row(&row(f64::NAN, 1.0, &[1.0, 2.0])),
        Err(Error::InvalidParameter { name: "timestamp", .. })
    ));
    assert!(matches!(
        w.write_row(&row(-1.0, 1.0, &[1.0, 2.0])),
        Err(Error::InvalidParameter { name: "timestamp", .. })
    ));
    assert!(matches!(
        w.write_row(&row(0.0, f64::INFINITY, &[1.0, 2.0])),
        Err(Error::InvalidParameter { name: "confidence", .. })
    ));
    assert!(matches!(
        w.write_row(&row(0.0, 1.0, &[1.0, f64::NEG_INFINITY])),
        Err(Error::InvalidParameter { .. })
    ));
    w.write_row(&row(0.0, 1.0, &[1.0, f64::NAN])).unwrap();
    assert_eq!(w.rows_written(), 1);
}

#[test]
fn write_row_does_not_allocate_after_warm_up() {
    let dir = tempfile::tempdir().unwrap();
    let cols = all_columns();
    let mut w = FrameCsvWriter::create(dir.path().join("a.csv"), &cols).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let frames: Vec<Vec<f64>> = (0..200)
        .map(|_| (0..cols.len()).map(|_| rng.random_range(-1e3..1e3)).collect())
        .collect();
    let row = |f: usize| FrameRow {
        frame: f as u64,
        timestamp: f as f64 / 30.0,
        success: true,
        confidence: 0.9,
        values: &frames[f],
    };
    w.write_row(&row(0)).unwrap(); // warm-up
                                   // The counter works:
    let b = allocs();
    let v: Vec<u8> = Vec::with_capacity(std::hint::black_box(16));
    assert!(allocs() > b);
    drop(v);
    let before = allocs();
    for f in 1..200 {
        w.write_row(&row(f)).unwrap();
    }
    let n = allocs() - before;
    assert_eq!(n, 0, "{n} allocations in 199 rows");
    w.finish().unwrap();
}

const GOOD: &str = "frame,timestamp,success,confidence,a,b\n0,0,1,0.9,1.5,2\n1,0.04,0,0,nan,nan\n";

#[test]
fn malformed_csvs_are_rejected_with_line_numbers() {
    assert_eq!(parse_frame_csv(GOOD.as_bytes()).unwrap().rows.len(), 2);
    // Also spaces and CRLF.
    let crlf = "frame, timestamp, success, confidence, a\r\n0, 0, 1, 0.5, 3\r\n";
    assert_eq!(parse_frame_csv(crlf.as_bytes()).unwrap().rows[0].values, vec![3.0]);
    let cases = [
        ("", "line 1"),
        ("frame,timestamp,confidence,success,a\n", "line 1"),
        ("frame,timestamp,success,confidence,a,a\n", "line 1"),
        ("frame,timestamp,success,confidence,a,b\n0,0,1,0.9,1.5\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n0,0,1,0.9,1.5,2,3\n", "line 2"),
        (
            "frame,timestamp,success,confidence,a,b\n0,0,1,0.9,1,2\n1,nan,1,0.9,1,2\n",
            "line 3",
        ),
        ("frame,timestamp,success,confidence,a,b\n0,-1,1,0.9,1,2\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n0,0,2,0.9,1,2\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n0,0,1,nan,1,2\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n0,0,1,0.9,inf,2\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n0,0,1,0.9,x,2\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n-1,0,1,0.9,1,2\n", "line 2"),
        ("frame,timestamp,success,confidence,a,b\n0,0,1,0.9,1,2", "line 2"),
    ];
    for (text, line) in cases {
        match parse_frame_csv(text.as_bytes()) {
            Err(Error::Parse { reason, .. }) => assert!(reason.contains(line), "{text:?}: {reason}"),
            other => panic!("{text:?} accepted: {other:?}"),
        }
    }
}

#[test]
fn every_truncation_is_rejected_or_a_prefix() {
    let full = parse_frame_csv(GOOD.as_bytes()).unwrap();
    for len in 0..GOOD.len() {
        match parse_frame_csv(&GOOD.as_bytes()[..len]) {
            Ok(t) => {
                // Only cuts at line ends parse, and they give the first rows.
                assert!(GOOD.as_bytes()[len - 1] == b'\n');
                assert_eq!(t.rows[..], full.rows[..t.rows.len()]);
            }
            Err(Error::Parse { .. }) => {}
            Err(e) => panic!("{e:?}"),
        }
    }
}

#[test]
fn landmark_csv_rules() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lm.csv");
    let mut w = FrameCsvWriter::create(&p, &landmark_columns()).unwrap();
    let mut v = [0.0; 136];
    landmark_values(None, &mut v);
    // success = 1 with NaN landmarks is written (NaN is a valid value) ...
    w.write_row(&FrameRow {
        frame: 0,
        timestamp: 0.0,
        success: true,
        confidence: 1.0,
        values: &v,
    })
    .unwrap();
    w.finish().unwrap();
    // ... but the landmark reader refuses it, naming the line.
    match read_landmarks_csv(&p) {
        Err(Error::Parse { reason, path, .. }) => {
            assert!(reason.contains("line 2"), "{reason}");
            assert_eq!(path, p);
        }
        other => panic!("{other:?}"),
    }
    // A CSV without landmark columns.
    let q = dir.path().join("nolm.csv");
    std::fs::write(&q, GOOD).unwrap();
    assert!(matches!(read_landmarks_csv(&q), Err(Error::Parse { .. })));
}

/// A seeded mesh of 478 points with awkward f32 values (many digits, tiny, negative zero).
fn random_mesh(rng: &mut ChaCha8Rng) -> Vec<[f32; 3]> {
    (0..MESH_POINTS)
        .map(|i| match i % 97 {
            0 => [f32::MIN_POSITIVE, -0.0, 1.0e-40],
            1 => [0.1, 1.0e7 + 1.0, -123.456_79],
            _ => [
                rng.random_range(-50.0f32..700.0),
                rng.random_range(-50.0f32..500.0),
                rng.random_range(-80.0f32..80.0),
            ],
        })
        .collect()
}

/// The 478-point layout: the writer's values read back bit for bit (as f32), failed rows
/// give `None`, and the reader checks the sizes: a missing point, an extra point, a
/// 68-point file and a mesh file given to the 68-point reader are all errors.
#[test]
fn mesh_csv_round_trip_and_size_checks() {
    let cols = mesh_columns();
    assert_eq!(cols.len(), 3 * MESH_POINTS);
    assert_eq!(&cols[..4], ["x_0", "y_0", "z_0", "x_1"]);
    assert_eq!(cols[3 * 468], "x_468");
    assert_eq!(cols[cols.len() - 1], "z_477");
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("mesh.csv");
    let mut rng = ChaCha8Rng::seed_from_u64(478);
    let mut w = FrameCsvWriter::create(&p, &cols).unwrap();
    let mut values = vec![0.0; 3 * MESH_POINTS];
    let mut expected = Vec::new();
    for f in 0..40u64 {
        let mesh = (f % 5 != 2).then(|| random_mesh(&mut rng));
        mesh_values(mesh.as_deref(), &mut values).unwrap();
        w.write_row(&FrameRow {
            frame: f,
            timestamp: f as f64 / 25.0,
            success: mesh.is_some(),
            confidence: if mesh.is_some() { 0.9 } else { 0.0 },
            values: &values,
        })
        .unwrap();
        expected.push(mesh);
    }
    w.finish().unwrap();
    // the shortest f32 form keeps rows short: 0.1f32 is written 0.1, not 0.10000000149...
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.lines().nth(1).unwrap().contains(",0.1,"), "shortest form");
    let back = read_mesh_csv(&p).unwrap();
    assert_eq!(back.len(), expected.len());
    for (r, want) in back.iter().zip(&expected) {
        assert_eq!(r.success, want.is_some());
        match (&r.points, want) {
            (Some(got), Some(want)) => {
                for (g, w) in got.iter().zip(want) {
                    for (a, b) in g.iter().zip(w) {
                        assert_eq!(a.to_bits(), b.to_bits(), "frame {}: {a} vs {b}", r.frame);
                    }
                }
            }
            (None, None) => {}
            other => panic!("frame {}: {other:?}", r.frame),
        }
    }
    // wrong sizes on the writing side
    assert!(mesh_values(Some(&[[0.0; 3]; 68]), &mut values).is_err());
    assert!(mesh_values(None, &mut values[..10]).is_err());
    // the 68-point reader refuses a mesh file (its x_0..y_67 are not iBUG points)
    match read_landmarks_csv(&p) {
        Err(Error::Parse { reason, .. }) => assert!(reason.contains("face mesh"), "{reason}"),
        other => panic!("{other:?}"),
    }
    // a file with one point missing, one with a point too many, a 68-point file
    let rows = |cols: &[String]| {
        let mut s = format!("frame,timestamp,success,confidence,{}\n", cols.join(","));
        s.push_str("0,0,1,1");
        for _ in cols {
            s.push_str(",1.5");
        }
        s.push('\n');
        s
    };
    let short: Vec<String> = cols.iter().filter(|c| *c != "y_477").cloned().collect();
    let long: Vec<String> = cols.iter().cloned().chain(["x_478".to_string()]).collect();
    for (name, body, want) in [
        ("short.csv", rows(&short), "y_477 missing"),
        ("long.csv", rows(&long), "x_478"),
        ("ibug.csv", rows(&landmark_columns()), "z_0 missing"),
    ] {
        let q = dir.path().join(name);
        std::fs::write(&q, body).unwrap();
        match read_mesh_csv(&q) {
            Err(Error::Parse { reason, path, .. }) => {
                assert!(reason.contains(want), "{name}: {reason}");
                assert_eq!(path, q);
            }
            other => panic!("{name}: {other:?}"),
        }
    }
    // a NaN point in a successful row is refused with its line
    let q = dir.path().join("nan.csv");
    std::fs::write(&q, rows(&cols).replacen(",1.5", ",nan", 1)).unwrap();
    match read_mesh_csv(&q) {
        Err(Error::Parse { reason, .. }) => assert!(reason.contains("line 2") && reason.contains("x_0"), "{reason}"),
        other => panic!("{other:?}"),
    }
    // the full file through the generic reader: 1434 value columns
    assert_eq!(read_frame_csv(&p).unwrap().columns.len(), 3 * MESH_POINTS);
}

/// Every f32 written by `mesh_values` reads back to the same bits (seeded bit patterns over
/// the whole finite range, so the shortest-form conversion is checked beyond the mesh's
/// usual pixel values).
#[test]
fn mesh_values_round_trip_any_finite_f32() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut values = vec![0.0; 3 * MESH_POINTS];
    for _ in 0..200 {
        let mesh: Vec<[f32; 3]> = (0..MESH_POINTS)
            .map(|_| {
                std::array::from_fn(|_| loop {
                    let v = f32::from_bits(rng.random());
                    if v.is_finite() {
                        break v;
                    }
                })
            })
            .collect();
        mesh_values(Some(&mesh), &mut values).unwrap();
        for (v, p) in values.iter().zip(mesh.iter().flatten()) {
            let text = format!("{v}");
            let back: f64 = text.parse().unwrap();
            assert_eq!((back as f32).to_bits(), p.to_bits(), "{p:e} -> {text}");
        }
    }
}
