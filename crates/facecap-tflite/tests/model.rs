//! The model reader's pieces: float16 conversion, graph checks, TFLite padding.

use facecap_tflite::model::*;

#[test]
fn f16_conversion_known_values() {
    assert_eq!(f16_to_f32(0x3c00), 1.0);
    assert_eq!(f16_to_f32(0xc000), -2.0);
    assert_eq!(f16_to_f32(0x7bff), 65504.0);
    assert_eq!(f16_to_f32(0x0001), 5.960_464_5e-8);
    assert_eq!(f16_to_f32(0x3555), 0.333_251_95);
    assert!(f16_to_f32(0x7c00).is_infinite());
    assert!(f16_to_f32(0x7e00).is_nan());
    assert_eq!(f16_to_f32(0x8000).to_bits(), 0x8000_0000);
}

#[test]
fn hand_built_graphs_with_bad_indices_or_ranks_are_errors() {
    let tensor = |shape: Vec<usize>, data: Option<Vec<f32>>| Tensor {
        name: String::new(),
        shape,
        data,
        int_data: None,
    };
    let win = Window {
        kh: 1,
        kw: 1,
        sh: 1,
        sw: 1,
        dh: 1,
        dw: 1,
        padding: Padding::Valid,
    };
    let conv = |filter| Op::Conv2d {
        input: 0,
        filter,
        bias: None,
        output: 2,
        win,
        act: Activation::None,
    };
    let mut g = Graph {
        tensors: vec![
            tensor(vec![1, 2, 2, 3], None),
            tensor(vec![4, 3], Some(vec![0.0; 12])),
            tensor(vec![1, 2, 2, 4], None),
        ],
        ops: vec![conv(1)],
        inputs: vec![0],
        outputs: vec![2],
    };
    assert!(g.check().is_err(), "rank-2 filter accepted");
    g.ops = vec![conv(7)];
    assert!(g.check().is_err(), "out-of-range filter accepted");
    g.tensors[1] = tensor(vec![4, 1, 1, 3], Some(vec![0.0; 12]));
    g.ops = vec![conv(1)];
    assert!(g.check().is_ok());
    g.outputs = vec![9];
    assert!(g.check().is_err(), "out-of-range output accepted");
}

#[test]
fn same_and_valid_padding_follow_tflite() {
    // 128 -> 64 with a 5x5 stride-2 SAME window: total pad 3, 1 before.
    assert_eq!(Window::out_and_pad(128, 5, 2, 1, Padding::Same), Some((64, 1)));
    assert_eq!(Window::out_and_pad(64, 3, 1, 1, Padding::Same), Some((64, 1)));
    assert_eq!(Window::out_and_pad(64, 2, 2, 1, Padding::Valid), Some((32, 0)));
    assert_eq!(Window::out_and_pad(1, 3, 1, 1, Padding::Valid), None);
}
