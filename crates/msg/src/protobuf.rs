//! The protocol-buffers wire format, writing only: the few field kinds that
//! the ONNX export (`rotorhive-model`) and the TensorBoard event files
//! (`rotorhive-records`) need. Both write a handful of message types, so no
//! schema crate or protobuf runtime is pulled in for them.

/// Appends `v` as a base-128 varint.
pub fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8 & 0x7f) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// A length-delimited field (wire type 2): bytes, a string or a message.
pub fn bytes(out: &mut Vec<u8>, field: u32, data: &[u8]) {
    varint(out, u64::from(field << 3 | 2));
    varint(out, data.len() as u64);
    out.extend_from_slice(data);
}

/// A varint field (wire type 0).
pub fn int(out: &mut Vec<u8>, field: u32, v: u64) {
    varint(out, u64::from(field << 3));
    varint(out, v);
}

/// A 64-bit fixed field (wire type 1), as a double.
pub fn double(out: &mut Vec<u8>, field: u32, v: f64) {
    varint(out, u64::from(field << 3 | 1));
    out.extend_from_slice(&v.to_le_bytes());
}

/// A 32-bit fixed field (wire type 5), as a float.
pub fn float(out: &mut Vec<u8>, field: u32, v: f32) {
    varint(out, u64::from(field << 3 | 5));
    out.extend_from_slice(&v.to_le_bytes());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_encode_as_the_protobuf_documentation_shows() {
        // protobuf.dev's encoding guide: 150 in field 1 is 08 96 01, the
        // string "testing" in field 2 is 12 07 74 65 73 74 69 6e 67.
        let mut out = Vec::new();
        int(&mut out, 1, 150);
        bytes(&mut out, 2, b"testing");
        assert_eq!(out, [0x08, 0x96, 0x01, 0x12, 0x07, b't', b'e', b's', b't', b'i', b'n', b'g']);
        let mut out = Vec::new();
        double(&mut out, 1, 1.0);
        float(&mut out, 2, 1.0);
        assert_eq!(out[0], 0x09);
        assert_eq!(out[9], 0x15);
        assert_eq!(out.len(), 14);
        let mut out = Vec::new();
        varint(&mut out, u64::MAX);
        assert_eq!(out.len(), 10);
    }
}
