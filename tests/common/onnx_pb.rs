//! A minimal protobuf writer, enough for ONNX's messages: tests build their models byte by
//! byte (no model file is downloaded or committed).

/// One protobuf message being written.
#[derive(Default)]
pub struct Pb(pub Vec<u8>);

impl Pb {
    pub fn varint(&mut self, mut v: u64) {
        while v >= 0x80 {
            self.0.push((v as u8) | 0x80);
            v >>= 7;
        }
        self.0.push(v as u8);
    }
    pub fn key(&mut self, field: u32, wire: u32) {
        self.varint(u64::from((field << 3) | wire));
    }
    pub fn int(mut self, field: u32, v: i64) -> Self {
        self.key(field, 0);
        self.varint(v as u64);
        self
    }
    pub fn bytes(mut self, field: u32, b: &[u8]) -> Self {
        self.key(field, 2);
        self.varint(b.len() as u64);
        self.0.extend_from_slice(b);
        self
    }
    pub fn string(self, field: u32, s: &str) -> Self {
        self.bytes(field, s.as_bytes())
    }
    pub fn msg(self, field: u32, m: Pb) -> Self {
        self.bytes(field, &m.0)
    }
}

/// A dimension of a declared input or output.
#[derive(Clone, Copy)]
pub enum Dim {
    Fixed(i64),
    Named(&'static str),
}
pub use Dim::{Fixed, Named};

/// `ValueInfoProto` of a float tensor.
pub fn value_info(name: &str, dims: &[Dim]) -> Pb {
    let shape = dims.iter().fold(Pb::default(), |shape, d| {
        shape.msg(
            1,
            match d {
                Fixed(v) => Pb::default().int(1, *v),
                Named(s) => Pb::default().string(2, s),
            },
        )
    });
    let tensor = Pb::default().int(1, 1).msg(2, shape);
    Pb::default()
        .string(1, name)
        .msg(2, Pb::default().msg(1, tensor))
}

/// `TensorProto` of float weights (raw little-endian data).
pub fn initializer(name: &str, dims: &[i64], data: &[f32]) -> Pb {
    let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    let t = dims.iter().fold(Pb::default(), |t, &d| t.int(1, d));
    t.int(2, 1).string(8, name).bytes(9, &raw)
}

/// `NodeProto`; `ints` are INTS attributes.
pub fn node(op: &str, inputs: &[&str], output: &str, ints: &[(&str, &[i64])]) -> Pb {
    let mut n = inputs
        .iter()
        .fold(Pb::default(), |n, i| n.string(1, i))
        .string(2, output)
        .string(4, op);
    for (name, values) in ints {
        let a = values
            .iter()
            .fold(Pb::default().string(1, name), |a, &v| a.int(8, v));
        n = n.msg(5, a.int(20, 7));
    }
    n
}

/// `node` with an INT attribute added.
pub fn with_int(node: Pb, name: &str, v: i64) -> Pb {
    node.msg(5, Pb::default().string(1, name).int(3, v).int(20, 2))
}

/// Serialised `ModelProto` (IR 7, opset 13) of one graph with one input and one output.
pub fn model(nodes: Vec<Pb>, inits: Vec<Pb>, input: Pb, output: Pb) -> Vec<u8> {
    graph_model(nodes, inits, vec![input], vec![output])
}

/// Serialised `ModelProto` (IR 7, opset 13) of one graph with any inputs and outputs.
pub fn graph_model(nodes: Vec<Pb>, inits: Vec<Pb>, inputs: Vec<Pb>, outputs: Vec<Pb>) -> Vec<u8> {
    let mut g = Pb::default();
    for n in nodes {
        g = g.msg(1, n);
    }
    g = g.string(2, "test");
    for i in inits {
        g = g.msg(5, i);
    }
    for i in inputs {
        g = g.msg(11, i);
    }
    for o in outputs {
        g = g.msg(12, o);
    }
    Pb::default()
        .int(1, 7)
        .msg(8, Pb::default().int(2, 13))
        .msg(7, g)
        .0
}

/// `TensorProto` of int64 values (raw little-endian data); no dims: a scalar.
pub fn int64_initializer(name: &str, dims: &[i64], data: &[i64]) -> Pb {
    let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    let t = dims.iter().fold(Pb::default(), |t, &d| t.int(1, d));
    t.int(2, 7).string(8, name).bytes(9, &raw)
}

/// `node` with a TENSOR attribute added (a `Constant`'s `value`).
pub fn with_tensor(node: Pb, name: &str, tensor: Pb) -> Pb {
    node.msg(5, Pb::default().string(1, name).msg(5, tensor).int(20, 4))
}
