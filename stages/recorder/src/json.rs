//! JSON views of frames, generated from the frame layouts so they cannot drift from the structs:
//! a JSON Schema per frame type and a JSON object per frame. Foxglove and other mcap tools decode
//! these channels without generated code.

use imuflow_graph::frames::{FieldLayout, FrameLayout, ScalarType};
use serde_json::{Map, Value, json};

/// The JSON Schema of a frame type's JSON encoding (nested objects for `header.*` fields).
pub fn schema(layout: &FrameLayout) -> Value {
    let mut header = Map::new();
    let mut properties = Map::new();
    for field in &layout.fields {
        let (target, name) = match field.name.strip_prefix("header.") {
            Some(rest) => (&mut header, rest),
            None => (&mut properties, field.name),
        };
        target.insert(name.to_owned(), field_schema(field));
    }
    properties.insert(
        "header".into(),
        json!({ "type": "object", "properties": Value::Object(header) }),
    );
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": layout.type_name,
        "type": "object",
        "properties": Value::Object(properties),
    })
}

fn field_schema(field: &FieldLayout) -> Value {
    let mut s = json!({
        "type": if field.scalar == ScalarType::F32 { "number" } else { "integer" },
        "description": field.doc,
    });
    for &n in field.shape.iter().rev() {
        s = json!({ "type": "array", "items": s, "minItems": n, "maxItems": n });
    }
    s
}

/// Decodes frame bytes (little-endian, as laid out) into a JSON object. Non-finite floats become
/// `null`, since JSON has no NaN.
pub fn encode(layout: &FrameLayout, bytes: &[u8]) -> Value {
    let mut header = Map::new();
    let mut object = Map::new();
    for field in &layout.fields {
        let value = field_value(field, bytes);
        match field.name.strip_prefix("header.") {
            Some(rest) => header.insert(rest.to_owned(), value),
            None => object.insert(field.name.to_owned(), value),
        };
    }
    object.insert("header".into(), Value::Object(header));
    Value::Object(object)
}

fn field_value(field: &FieldLayout, bytes: &[u8]) -> Value {
    let size = field.scalar.size();
    let scalars: Vec<Value> = (0..field.len())
        .map(|i| {
            let at = field.offset + i * size;
            let Some(b) = bytes.get(at..at + size) else {
                return Value::Null;
            };
            match field.scalar {
                ScalarType::F32 => {
                    let x = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    serde_json::Number::from_f64(f64::from(x)).map_or(Value::Null, Value::Number)
                }
                ScalarType::U32 => json!(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ScalarType::U64 => json!(u64::from_le_bytes([
                    b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]
                ])),
            }
        })
        .collect();
    nest(&field.shape, &mut scalars.into_iter())
}

fn nest(shape: &[usize], flat: &mut impl Iterator<Item = Value>) -> Value {
    match shape.split_first() {
        None => flat.next().unwrap_or(Value::Null),
        Some((&n, rest)) => Value::Array((0..n).map(|_| nest(rest, flat)).collect()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_graph::frames::{Frame, ImuFrame};

    #[test]
    fn encodes_nested_arrays_header_and_nan() {
        let mut f = ImuFrame::default();
        f.header.seq = 7;
        f.orientation_wxyz[1] = [0.5, -0.5, 0.25, f32::NAN];
        f.valid_mask = 0b11_1101;
        let v = encode(ImuFrame::layout(), bytemuck::bytes_of(&f));
        assert_eq!(v["header"]["seq"], json!(7));
        assert_eq!(v["orientation_wxyz"][1], json!([0.5, -0.5, 0.25, null]));
        assert_eq!(
            v["orientation_wxyz"].as_array().map(Vec::len),
            Some(imuflow_graph::frames::MAX_SITES)
        );
        assert_eq!(v["valid_mask"], json!(61));
    }

    #[test]
    fn schema_describes_every_field() {
        let s = schema(ImuFrame::layout());
        let props = s["properties"].as_object().expect("object");
        assert_eq!(
            props["specific_force_mps2"]["minItems"],
            json!(imuflow_graph::frames::MAX_SITES)
        );
        assert_eq!(props["specific_force_mps2"]["items"]["maxItems"], json!(3));
        assert_eq!(
            props["header"]["properties"]["flags"]["type"],
            json!("integer")
        );
        // Every non-header field plus the header object.
        let non_header = ImuFrame::layout()
            .fields
            .iter()
            .filter(|f| !f.name.starts_with("header."))
            .count();
        assert_eq!(props.len(), non_header + 1);
    }
}
