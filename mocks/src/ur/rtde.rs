//! The RTDE server (30004) of the mock controller: protocol negotiation, controller version,
//! output and input recipes, start/pause, and data packages streamed at the requested
//! frequency (docs/protocols.md §2.2–2.5).

use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpStream;
use tokio::time::MissedTickBehavior;

use super::wire::{self, kind, FieldType, Package};
use super::{closed, RtdeRequest, Shared};

/// e-Series controllers stream at most 500 Hz.
const MAX_FREQUENCY_HZ: f64 = 500.0;

struct OutputRecipe {
    id: u8,
    names: Vec<String>,
    types: Vec<FieldType>,
    frequency_hz: f64,
}

struct Session {
    connection: u64,
    protocol: u16,
    output: Option<OutputRecipe>,
    inputs: Vec<(Vec<String>, Vec<FieldType>)>,
    streaming: bool,
}

impl Session {
    /// The reply to one request, if it has one.
    fn handle(&mut self, shared: &Shared, p: &Package) -> Option<Package> {
        shared.record(RtdeRequest {
            connection: self.connection,
            kind: p.kind,
            payload: p.payload.clone(),
        });
        let reply = |kind: u8, payload: Vec<u8>| Some(Package { kind, payload });
        match p.kind {
            kind::PROTOCOL_VERSION => {
                let v = p.payload.get(..2).map(|b| u16::from_be_bytes([b[0], b[1]]));
                let ok = matches!(v, Some(1 | 2));
                if let Some(v) = v.filter(|_| ok) {
                    self.protocol = v;
                }
                reply(kind::PROTOCOL_VERSION, vec![ok as u8])
            }
            kind::CONTROL_VERSION => {
                let v = shared.with(|c| c.cfg.version);
                reply(
                    kind::CONTROL_VERSION,
                    v.iter().flat_map(|x| x.to_be_bytes()).collect(),
                )
            }
            kind::SETUP_OUTPUTS => {
                let (frequency_hz, names) = if self.protocol >= 2 && p.payload.len() >= 8 {
                    let f = f64::from_be_bytes(p.payload[..8].try_into().expect("8 bytes"));
                    (f, wire::split_names(&p.payload[8..]))
                } else {
                    (125.0, wire::split_names(&p.payload))
                };
                let id = self.output.as_ref().map_or(1, |o| o.id.wrapping_add(1));
                let types: Vec<Option<FieldType>> =
                    names.iter().map(|n| wire::output_type(n)).collect();
                let answer: Vec<&str> = types
                    .iter()
                    .map(|t| t.map_or("NOT_FOUND", FieldType::name))
                    .collect();
                let valid = !names.is_empty()
                    && types.iter().all(Option::is_some)
                    && frequency_hz.is_finite()
                    && frequency_hz > 0.0;
                if valid {
                    self.output = Some(OutputRecipe {
                        id,
                        types: types.into_iter().flatten().collect(),
                        names,
                        frequency_hz: frequency_hz.min(MAX_FREQUENCY_HZ),
                    });
                }
                let mut out = vec![if valid { id } else { 0 }];
                out.extend_from_slice(answer.join(",").as_bytes());
                reply(kind::SETUP_OUTPUTS, out)
            }
            kind::SETUP_INPUTS => {
                let names = wire::split_names(&p.payload);
                let types: Vec<Option<FieldType>> =
                    names.iter().map(|n| wire::input_type(n)).collect();
                let answer: Vec<&str> = types
                    .iter()
                    .map(|t| t.map_or("NOT_FOUND", FieldType::name))
                    .collect();
                let valid = !names.is_empty() && types.iter().all(Option::is_some);
                // ur_rtde hard-codes input recipe ids 1, 2, 3, … in setup order.
                let id = if valid {
                    self.inputs
                        .push((names, types.into_iter().flatten().collect()));
                    self.inputs.len() as u8
                } else {
                    0
                };
                let mut out = vec![id];
                out.extend_from_slice(answer.join(",").as_bytes());
                reply(kind::SETUP_INPUTS, out)
            }
            kind::START => {
                self.streaming = self.output.is_some();
                reply(kind::START, vec![self.streaming as u8])
            }
            kind::PAUSE => {
                self.streaming = false;
                reply(kind::PAUSE, vec![1])
            }
            kind::DATA => {
                let (&id, fields) = p.payload.split_first()?;
                let (names, types) = self.inputs.get((id as usize).wrapping_sub(1))?;
                if let Some(values) = wire::decode_values(types, fields) {
                    shared.with(|c| {
                        for (n, v) in names.iter().zip(&values) {
                            c.input(n, v);
                        }
                    });
                }
                None
            }
            _ => None,
        }
    }

    fn data_package(&self, shared: &Shared) -> Option<Package> {
        let o = self.output.as_ref()?;
        let mut payload = vec![o.id];
        shared.with(|c| {
            for (n, t) in o.names.iter().zip(&o.types) {
                wire::encode_value(&mut payload, *t, &c.output(n));
            }
        });
        Some(Package {
            kind: kind::DATA,
            payload,
        })
    }
}

pub(super) async fn serve_rtde(
    shared: Arc<Shared>,
    stream: TcpStream,
    connection: u64,
    generation: u64,
) {
    let mut rx = shared.links.subscribe();
    let (mut read, mut write) = stream.into_split();
    let mut s = Session {
        connection,
        protocol: 1,
        output: None,
        inputs: Vec::new(),
        streaming: false,
    };
    let period = |s: &Session| {
        Duration::from_secs_f64(1.0 / s.output.as_ref().map_or(125.0, |o| o.frequency_hz))
    };
    let mut ticker = tokio::time::interval(period(&s));
    ticker.set_missed_tick_behavior(MissedTickBehavior::Skip);
    loop {
        tokio::select! {
            p = wire::read_package(&mut read) => {
                let p = match p {
                    Ok(Some(p)) => p,
                    _ => return,
                };
                let was_streaming = s.streaming;
                let reply = s.handle(&shared, &p);
                if let Some(r) = reply {
                    if wire::write_package(&mut write, r.kind, &r.payload).await.is_err() {
                        return;
                    }
                }
                if s.streaming && !was_streaming {
                    ticker = tokio::time::interval(period(&s));
                    ticker.set_missed_tick_behavior(MissedTickBehavior::Skip);
                }
            }
            _ = ticker.tick(), if s.streaming => {
                if let Some(d) = s.data_package(&shared) {
                    if wire::write_package(&mut write, d.kind, &d.payload).await.is_err() {
                        return;
                    }
                }
            }
            _ = closed(&mut rx, generation) => return,
        }
    }
}
