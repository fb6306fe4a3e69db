//! The kernels against slow, obvious references, and every SIMD level against the
//! portable kernels' bits.

use facecap_tflite::interp::single::{conv_window, depthwise_at, gemm_at};
use facecap_tflite::kernels::*;
use facecap_tflite::model::{Activation, Padding, Window};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn rnd(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

/// A `k x k` window of stride `s`, dilation 1.
fn square_window(k: usize, s: usize, padding: Padding) -> Window {
    Window {
        kh: k,
        kw: k,
        sh: s,
        sw: s,
        dh: 1,
        dw: 1,
        padding,
    }
}

/// Geometry, input, filter and bias of a random convolution.
type RandomConv = (Geom, Vec<f32>, Vec<f32>, Vec<f32>);

/// A `k x k` stride-`s` convolution (dilation 1) on an `ih x iw x ic` input with `oc`
/// outputs: its geometry and random input, filter and bias (`None` when the window
/// does not fit).
#[allow(clippy::too_many_arguments)]
fn random_conv(
    rng: &mut ChaCha8Rng,
    ih: usize,
    iw: usize,
    ic: usize,
    oc: usize,
    k: usize,
    s: usize,
    padding: Padding,
) -> Option<RandomConv> {
    let g = Geom::new(ih, iw, ic, square_window(k, s, padding))?;
    Some((g, rnd(rng, ih * iw * ic), rnd(rng, oc * k * k * ic), rnd(rng, oc)))
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn conv_fast_matches_reference_on_random_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(16);
    for case in 0..60 {
        let k = [1usize, 2, 3, 5][case % 4];
        // Up to 40x40 outputs: several chunks of im2col rows.
        let big = case % 5 == 0;
        let s = 1 + (case / 4) % 2;
        let padding = if case % 3 == 0 { Padding::Valid } else { Padding::Same };
        let top = if big { 40 } else { 12 };
        let (ih, iw) = (rng.random_range(k..top), rng.random_range(k..top));
        let ic = rng.random_range(1..20);
        let oc = rng.random_range(1..40);
        let Some((g, input, filter, bias)) = random_conv(&mut rng, ih, iw, ic, oc, k, s, padding) else {
            continue;
        };
        let act = if case % 2 == 0 {
            Activation::Relu
        } else {
            Activation::None
        };
        let want = reference::conv(&input, &g, &filter, Some(&bias), oc, act);
        let packed = Packed::new(&filter, Some(&bias), oc, k * k * ic);
        let mut got = vec![0.0; g.oh * g.ow * oc];
        if g.is_pointwise() {
            gemm(&input, g.oh * g.ow, &packed, &Epilogue::act(act), &mut got);
        } else {
            let mut col = vec![0.0; g.im2col_len()];
            im2col(&input, &g, &mut col);
            gemm(&col, g.oh * g.ow, &packed, &Epilogue::act(act), &mut got);
            // Chunk by chunk through a scratch of one chunk, with a residual.
            let res = rnd(&mut rng, g.oh * g.ow * oc);
            let ep = Epilogue {
                act,
                residual: Some(&res),
                post: Post::Relu,
            };
            let rows = (g.oh * g.ow).min(im2col_chunk_rows(k * k * ic));
            let mut scratch = vec![0.0; rows * k * k * ic];
            // The portable level runs KxK windows as chunked im2col + GEMM, the register
            // levels with their direct kernels (and dilated windows as im2col, below).
            let mut chunked = vec![0.0; g.oh * g.ow * oc];
            conv_window(Level::Portable, &input, &g, &packed, &ep, &mut scratch, &mut chunked);
            for level in Level::all() {
                let mut direct = vec![0.0; g.oh * g.ow * oc];
                conv_window(level, &input, &g, &packed, &ep, &mut scratch, &mut direct);
                for (what, got) in [("chunked", &chunked), ("direct", &direct)] {
                    let d = got
                        .iter()
                        .zip(&want)
                        .zip(&res)
                        .map(|((c, w), r)| (c - (w + r).max(0.0)).abs())
                        .fold(0.0, f32::max);
                    assert!(d < 1e-4, "case {case} {level:?} {what}: max difference {d}");
                }
            }
        }
        let d = max_diff(&got, &want);
        assert!(d < 1e-4, "case {case}: max difference {d}");
    }
}

/// The convolution `g` with a random residual and PReLU in its epilogue, at every level,
/// against the reference (`what` names the case in a failure).
fn check_residual_prelu(
    rng: &mut ChaCha8Rng,
    what: &str,
    g: &Geom,
    input: &[f32],
    filter: &[f32],
    bias: &[f32],
    oc: usize,
) {
    let res = rnd(rng, g.oh * g.ow * oc);
    let alpha = rnd(rng, oc);
    let conv = reference::conv(input, g, filter, Some(bias), oc, Activation::None);
    let want: Vec<f32> = conv
        .iter()
        .zip(&res)
        .enumerate()
        .map(|(i, (&c, &r))| {
            let v = c + r;
            if v >= 0.0 {
                v
            } else {
                v * alpha[i % oc]
            }
        })
        .collect();
    let kk = g.win.kh * g.win.kw * g.ic;
    let packed = Packed::new(filter, Some(bias), oc, kk);
    let ep = Epilogue {
        act: Activation::None,
        residual: Some(&res),
        post: Post::Prelu(&alpha),
    };
    let rows = (g.oh * g.ow).min(im2col_chunk_rows(kk));
    let mut scratch = vec![0.0; rows * kk];
    for level in Level::all() {
        let mut got = vec![0.0; g.oh * g.ow * oc];
        conv_window(level, input, g, &packed, &ep, &mut scratch, &mut got);
        let d = max_diff(&got, &want);
        assert!(d < 1e-4, "{what} {level:?}: max difference {d}");
    }
}

/// The direct (no im2col) convolution on the shapes it is used for and around them:
/// 3x3/2 on 3 channels (the landmark model's first layer), 2x2/2, 5x5/2, stride 1,
/// odd and even sizes (padding on one or both sides), output channel counts that
/// are not multiples of 8, and a residual and PReLU in the epilogue.
#[test]
fn conv_window_matches_reference_at_borders() {
    let mut rng = ChaCha8Rng::seed_from_u64(19);
    for case in 0..48 {
        let (k, s) = [(3usize, 2usize), (2, 2), (5, 2), (3, 1)][case % 4];
        let padding = if case % 6 == 5 { Padding::Valid } else { Padding::Same };
        let ic = [3usize, 1, 16, 5][(case / 4) % 4];
        let oc = [16usize, 5, 24, 8, 40, 13][(case / 2) % 6];
        let (ih, iw) = (rng.random_range(k..24), rng.random_range(k..24));
        let Some((g, input, filter, bias)) = random_conv(&mut rng, ih, iw, ic, oc, k, s, padding) else {
            continue;
        };
        let what = format!("case {case} {ih}x{iw}x{ic} -> {oc} k{k}/{s}");
        check_residual_prelu(&mut rng, &what, &g, &input, &filter, &bias, oc);
    }
}

/// Dilated windows, which every level runs as chunked im2col + its GEMM, against the
/// reference, with a residual and PReLU in the epilogue.
#[test]
fn dilated_conv_matches_reference_at_every_level() {
    let mut rng = ChaCha8Rng::seed_from_u64(37);
    for case in 0..24 {
        let (k, s, dil) = [(3usize, 1usize, 2usize), (3, 2, 2), (2, 1, 3), (5, 1, 2)][case % 4];
        let padding = if case % 3 == 0 { Padding::Valid } else { Padding::Same };
        let ic = [3usize, 8, 13][(case / 4) % 3];
        let oc = [16usize, 5, 24, 40][case % 4];
        let big = case % 6 == 0; // several chunks of im2col rows
        let top = if big { 48 } else { 16 };
        let (ih, iw) = (rng.random_range(k * dil..top), rng.random_range(k * dil..top));
        let win = Window {
            dh: dil,
            dw: dil,
            ..square_window(k, s, padding)
        };
        let Some(g) = Geom::new(ih, iw, ic, win) else {
            continue;
        };
        let (input, filter, bias) = (
            rnd(&mut rng, ih * iw * ic),
            rnd(&mut rng, oc * k * k * ic),
            rnd(&mut rng, oc),
        );
        let what = format!("case {case} {ih}x{iw}x{ic} -> {oc} k{k}/{s} dilation {dil}");
        check_residual_prelu(&mut rng, &what, &g, &input, &filter, &bias, oc);
    }
}

#[test]
fn simd_gemm_with_epilogue_matches_reference() {
    let mut rng = ChaCha8Rng::seed_from_u64(18);
    for case in 0..30 {
        let rows = rng.random_range(1..40);
        let k = rng.random_range(1..70);
        let n = rng.random_range(1..50);
        let a = rnd(&mut rng, rows * k);
        let w = rnd(&mut rng, n * k);
        let bias = rnd(&mut rng, n);
        let res = rnd(&mut rng, rows * n);
        let alpha = rnd(&mut rng, n);
        let packed = Packed::new(&w, Some(&bias), n, k);
        let ep = Epilogue {
            act: if case % 2 == 0 {
                Activation::Relu6
            } else {
                Activation::None
            },
            residual: Some(&res),
            post: Post::Prelu(&alpha),
        };
        let mut want = vec![0.0f32; rows * n];
        for p in 0..rows {
            for co in 0..n {
                let mut s = bias[co] as f64;
                for kk in 0..k {
                    s += (a[p * k + kk] * w[co * k + kk]) as f64;
                }
                let v = ep.act.apply(s as f32) + res[p * n + co];
                want[p * n + co] = if v >= 0.0 { v } else { v * alpha[co] };
            }
        }
        for level in Level::all() {
            let mut got = vec![0.0; rows * n];
            gemm_at(level, &a, rows, &packed, &ep, &mut got);
            let d = max_diff(&got, &want);
            assert!(d < 1e-4, "case {case} {level:?}: max difference {d}");
        }
    }
}

#[test]
fn depthwise_fast_matches_reference_on_random_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    for case in 0..80 {
        let k = [3usize, 5, 2][case % 3];
        let s = 1 + case % 2;
        let padding = if case % 4 == 0 { Padding::Valid } else { Padding::Same };
        let (ih, iw) = (rng.random_range(k..14), rng.random_range(k..14));
        // Multiples of 8 and other counts >= 8 exercise the register paths (3x3: any
        // count >= 8, blocks overlapping at the end), counts below 8 the portable one.
        // (Both strides with both kinds of channel counts.)
        let c = match case % 8 {
            0 | 1 => 8 * rng.random_range(1..7),
            2 | 3 => rng.random_range(9..50),
            _ => rng.random_range(1..50),
        };
        let win = square_window(k, s, padding);
        let Some(g) = Geom::new(ih, iw, c, win) else { continue };
        let input = rnd(&mut rng, ih * iw * c);
        let filter = rnd(&mut rng, k * k * c);
        let bias = rnd(&mut rng, c);
        let want = reference::depthwise(&input, &g, &filter, &bias, Activation::Relu6);
        for level in Level::all() {
            let mut got = vec![0.0; g.oh * g.ow * c];
            depthwise_at(
                level,
                &input,
                &g,
                &filter,
                &bias,
                &Epilogue::act(Activation::Relu6),
                &mut got,
            );
            let d = max_diff(&got, &want);
            assert!(d < 1e-5, "case {case} {level:?}: max difference {d}");
        }
    }
}

/// Every SIMD level this CPU has gives the portable kernels' bits (each output is
/// summed in the same order at every width), on the landmark model's layer shapes
/// (8 to 128 channels, 1x1, 2x2/2, 3x3/2, depthwise 3x3) and on odd ones around them.
#[test]
fn every_level_gives_the_same_bits() {
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    for case in 0..36 {
        let (k, s) = [(1usize, 1usize), (2, 2), (3, 2), (3, 1)][case % 4];
        let ic = [8usize, 16, 32, 3, 64, 13][(case / 4) % 6];
        let oc = [16usize, 8, 32, 64, 48, 40, 13, 128, 24][case % 9];
        let (ih, iw) = (rng.random_range(k..20), rng.random_range(k..20));
        let Some((g, input, filter, bias)) = random_conv(&mut rng, ih, iw, ic, oc, k, s, Padding::Same) else {
            continue;
        };
        let res = rnd(&mut rng, g.oh * g.ow * oc);
        let alpha = rnd(&mut rng, oc.max(ic));
        let ep = Epilogue {
            act: Activation::None,
            residual: Some(&res),
            post: Post::Prelu(&alpha[..oc]),
        };
        let packed = Packed::new(&filter, Some(&bias), oc, k * k * ic);
        let mut scratch = vec![0.0; g.oh * g.ow * k * k * ic];
        let dw_filter = rnd(&mut rng, 9 * ic);
        let dw_bias = rnd(&mut rng, ic);
        let dw_geom = Geom::new(ih, iw, ic, square_window(3, s, Padding::Same)).expect("3x3 fits");
        let dw_ep = Epilogue {
            act: Activation::None,
            residual: None,
            post: Post::Prelu(&alpha[..ic]),
        };
        let mut first: Option<(Vec<u32>, Vec<u32>)> = None;
        for level in Level::all() {
            let mut conv = vec![0.0; g.oh * g.ow * oc];
            if g.is_pointwise() {
                gemm_at(level, &input, g.oh * g.ow, &packed, &ep, &mut conv);
            } else {
                conv_window(level, &input, &g, &packed, &ep, &mut scratch, &mut conv);
            }
            let mut dw = vec![0.0; dw_geom.oh * dw_geom.ow * ic];
            depthwise_at(level, &input, &dw_geom, &dw_filter, &dw_bias, &dw_ep, &mut dw);
            let got = (bits(&conv), bits(&dw));
            match &first {
                None => first = Some(got),
                Some(want) => {
                    assert!(
                        got.0 == want.0,
                        "case {case}: {ih}x{iw}x{ic} -> {oc} k{k}/{s} at {level:?} differs from the portable bits"
                    );
                    assert!(
                        got.1 == want.1,
                        "case {case}: depthwise {ih}x{iw}x{ic}/{s} at {level:?} differs"
                    );
                }
            }
        }
    }
}

/// Convolutions whose output rows hold one pixel (the landmark model's heads: a 2x2
/// window over a 2x2 input, up to 1434 outputs), which AVX2 runs four panels at a time:
/// the portable bits at every level, and the reference within rounding, with and
/// without a residual and PReLU.
#[test]
fn single_pixel_rows_give_the_same_bits() {
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    for case in 0..28 {
        let ic = [16usize, 64, 128, 5][case % 4];
        let oc = [1usize, 16, 64, 72, 80, 100, 200][case % 7];
        let ih = if case % 3 == 0 { rng.random_range(3..6) } else { 2 };
        let Some((g, input, filter, bias)) = random_conv(&mut rng, ih, 2, ic, oc, 2, 1, Padding::Valid) else {
            continue;
        };
        assert_eq!(g.ow, 1);
        let res = rnd(&mut rng, g.oh * oc);
        let alpha = rnd(&mut rng, oc);
        let packed = Packed::new(&filter, Some(&bias), oc, 4 * ic);
        let mut scratch = vec![0.0; g.oh * 4 * ic];
        let plain = Epilogue::act(Activation::None);
        let fused = Epilogue {
            act: Activation::None,
            residual: Some(&res),
            post: Post::Prelu(&alpha),
        };
        let conv = reference::conv(&input, &g, &filter, Some(&bias), oc, Activation::None);
        for (e, ep) in [plain, fused].iter().enumerate() {
            let want: Vec<f32> = if e == 0 {
                conv.clone()
            } else {
                conv.iter()
                    .zip(&res)
                    .enumerate()
                    .map(|(i, (&c, &r))| if c + r >= 0.0 { c + r } else { (c + r) * alpha[i % oc] })
                    .collect()
            };
            let mut first: Option<Vec<u32>> = None;
            for level in Level::all() {
                let mut got = vec![0.0; g.oh * oc];
                conv_window(level, &input, &g, &packed, ep, &mut scratch, &mut got);
                let d = max_diff(&got, &want);
                assert!(
                    d < 1e-4,
                    "case {case} {ih}x2x{ic} -> {oc}, epilogue {e}, {level:?}: max difference {d}"
                );
                match &first {
                    None => first = Some(bits(&got)),
                    Some(b) => assert!(
                        *b == bits(&got),
                        "case {case} {ih}x2x{ic} -> {oc}, epilogue {e}: {level:?} differs from the portable bits"
                    ),
                }
            }
        }
    }
}

/// The 8-channel stride-1 3x3 depthwise layers, which AVX-512 runs two pixels to a
/// register, give the portable bits at every width from 1 to 37 pixels (blocks of
/// four pairs, a lone pair, an odd last pixel, borders) and both paddings.
#[test]
fn depthwise_pairs_give_the_same_bits() {
    let mut rng = ChaCha8Rng::seed_from_u64(29);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    for iw in 1..=37 {
        for padding in [Padding::Same, Padding::Valid] {
            let ih = rng.random_range(1..6);
            let Some(g) = Geom::new(ih, iw, 8, square_window(3, 1, padding)) else {
                continue;
            };
            let input = rnd(&mut rng, ih * iw * 8);
            let (filter, bias, alpha) = (rnd(&mut rng, 72), rnd(&mut rng, 8), rnd(&mut rng, 8));
            let ep = Epilogue {
                act: Activation::None,
                residual: None,
                post: Post::Prelu(&alpha),
            };
            let mut first: Option<Vec<u32>> = None;
            for level in Level::all() {
                let mut dw = vec![0.0; g.oh * g.ow * 8];
                depthwise_at(level, &input, &g, &filter, &bias, &ep, &mut dw);
                match &first {
                    None => first = Some(bits(&dw)),
                    Some(want) => assert!(
                        &bits(&dw) == want,
                        "depthwise {ih}x{iw}x8/1 {padding:?} at {level:?} differs"
                    ),
                }
            }
        }
    }
}

/// The `1x1 16 -> 8` layers, which AVX-512 runs two pixels to a register, give the
/// portable bits for 1 to 40 pixels (blocks of six pairs, lone pairs, an odd last
/// pixel) with every epilogue the model uses.
#[test]
fn pointwise_pairs_give_the_same_bits() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    for rows in 1..=40 {
        let input = rnd(&mut rng, rows * 16);
        let (filter, bias) = (rnd(&mut rng, 8 * 16), rnd(&mut rng, 8));
        let (res, alpha) = (rnd(&mut rng, rows * 8), rnd(&mut rng, 8));
        let packed = Packed::new(&filter, Some(&bias), 8, 16);
        let eps = [
            Epilogue {
                act: Activation::None,
                residual: None,
                post: Post::Prelu(&alpha),
            },
            Epilogue {
                act: Activation::Relu,
                residual: Some(&res),
                post: Post::None,
            },
            Epilogue {
                act: Activation::None,
                residual: Some(&res),
                post: Post::Relu,
            },
        ];
        for ep in &eps {
            let mut first: Option<Vec<u32>> = None;
            for level in Level::all() {
                let mut out = vec![0.0; rows * 8];
                gemm_at(level, &input, rows, &packed, ep, &mut out);
                match &first {
                    None => first = Some(bits(&out)),
                    Some(want) => assert!(&bits(&out) == want, "{rows} rows at {level:?} differ"),
                }
            }
        }
    }
}

/// Max pooling on random shapes (8-channel path with overlapping last block, and
/// the per-channel loop below 8 channels) against a plain per-element loop.
#[test]
fn max_pool_matches_plain_loop_on_random_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    for case in 0..40 {
        let (k, s) = [(2usize, 2usize), (3, 2), (3, 1), (2, 1)][case % 4];
        let padding = if case % 3 == 0 { Padding::Valid } else { Padding::Same };
        let c = [16usize, 28, 8, 5, 42, 1][case % 6];
        let (ih, iw) = (rng.random_range(k..15), rng.random_range(k..15));
        let win = square_window(k, s, padding);
        let Some(g) = Geom::new(ih, iw, c, win) else { continue };
        let input = rnd(&mut rng, ih * iw * c);
        let mut want = vec![f32::NEG_INFINITY; g.oh * g.ow * c];
        for oy in 0..g.oh {
            for ox in 0..g.ow {
                for ky in 0..k {
                    for kx in 0..k {
                        let (Some(iy), Some(ix)) = (g.iy(oy, ky), g.ix(ox, kx)) else {
                            continue;
                        };
                        for ch in 0..c {
                            let w = &mut want[(oy * g.ow + ox) * c + ch];
                            *w = w.max(input[(iy * iw + ix) * c + ch]);
                        }
                    }
                }
            }
        }
        for v in want.iter_mut() {
            *v = Activation::Relu6.apply(*v);
        }
        let mut got = vec![0.0; g.oh * g.ow * c];
        max_pool(&input, &g, Activation::Relu6, &mut got);
        assert_eq!(got, want, "case {case} {ih}x{iw}x{c} k{k}/{s}");
    }
}

/// Channel-only padding (written in place, 8 floats at a time) and spatial padding
/// against a plain per-element loop, on random shapes and pads.
#[test]
fn pad_matches_plain_loop_on_random_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    for case in 0..48 {
        let c = [1usize, 5, 8, 16, 24, 28, 42, 64][case % 8];
        let (h, w) = (rng.random_range(1..6), rng.random_range(1..6));
        let (before, after) = (rng.random_range(0..11), rng.random_range(0..11));
        let spatial = if case % 3 == 0 {
            [rng.random_range(0..2), rng.random_range(0..2)]
        } else {
            [0, 0]
        };
        let pads = [[0, 0], spatial, [0, spatial[1]], [before, after]];
        let (oh, ow, oc) = (h + spatial[0] + spatial[1], w + spatial[1], c + before + after);
        let input = rnd(&mut rng, h * w * c);
        let mut want = vec![0.0f32; oh * ow * oc];
        for y in 0..h {
            for x in 0..w {
                for ch in 0..c {
                    want[((y + spatial[0]) * ow + x) * oc + before + ch] = input[(y * w + x) * c + ch];
                }
            }
        }
        let mut got = vec![f32::NAN; oh * ow * oc];
        pad4(&input, [1, h, w, c], pads, &mut got);
        assert_eq!(got, want, "case {case} {h}x{w}x{c} pads {pads:?}");
    }
}

#[test]
fn pad_and_pool_small_cases() {
    // 1x2x2x1 -> pad 1 everywhere spatially and 1 channel after.
    let input = [1.0, 2.0, 3.0, 4.0];
    let mut out = vec![-1.0; 4 * 4 * 2];
    pad4(&input, [1, 2, 2, 1], [[0, 0], [1, 1], [1, 1], [0, 1]], &mut out);
    assert_eq!(out[(4 + 1) * 2], 1.0);
    assert_eq!(out[(2 * 4 + 2) * 2], 4.0);
    assert_eq!(out.iter().filter(|&&v| v != 0.0).count(), 4);
    let g = Geom::new(
        4,
        4,
        2,
        Window {
            kh: 2,
            kw: 2,
            sh: 2,
            sw: 2,
            dh: 1,
            dw: 1,
            padding: Padding::Valid,
        },
    )
    .unwrap_or_else(|| unreachable!());
    let mut pooled = vec![0.0; 2 * 2 * 2];
    max_pool(&out, &g, Activation::None, &mut pooled);
    assert_eq!(pooled, vec![1.0, 0.0, 2.0, 0.0, 3.0, 0.0, 4.0, 0.0]);
}
