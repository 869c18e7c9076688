//! Checking encoded tiles without decoding them: a walk over a QOI or LZ4
//! stream that follows its ops and counts the pixels (bytes) they would
//! produce, writing nothing.
//!
//! The master checks every tile a slave sends before it counts it, and for
//! a viewer that decodes the slave's codec it forwards the bytes as they
//! came, so decoding them only to throw the pixels away cost it about a
//! sixth of its CPU (12 slaves at 320×240). Both formats make validity a
//! matter of structure alone: a QOI op always yields a pixel (its index
//! cache and differences need no checking) and an LZ4 sequence is valid when
//! its literals are in the input and its match reaches back into what was
//! already produced. A walk is therefore as strict as a decoder, and it is
//! stricter than the ones this build uses where they are lenient (a QOI run
//! past the last pixel, an RGBA op in an RGB image, bytes after the end
//! marker, an LZ4 match at offset 0): the encoders never write those, and a
//! check that passes means every decoder produces the tile
//! ([`super::decode_into`] included).

/// The end marker of a QOI stream.
const QOI_END: [u8; 8] = [0, 0, 0, 0, 0, 0, 0, 1];
/// QOI's header size.
const QOI_HEADER: usize = 14;

/// Why a walk stopped.
pub(super) type WalkError = String;

/// Bytes each QOI op byte starts (0 for an RGBA op, which an RGB image
/// does not hold), and the pixels it yields.
const QOI_OPS: ([u8; 256], [u8; 256]) = {
    let (mut len, mut px) = ([0u8; 256], [0u8; 256]);
    let mut op = 0;
    while op < 256 {
        (len[op], px[op]) = match op {
            0xfe => (4, 1),
            0xff => (0, 0),
            0xc0..=0xfd => (1, (op & 0x3f) as u8 + 1),
            0x80..=0xbf => (2, 1),
            _ => (1, 1),
        };
        op += 1;
    }
    (len, px)
};

/// Walks the ops of a QOI stream (header already checked to name a
/// `pixels`-pixel RGB image): every op whole, exactly `pixels` pixels, then
/// the end marker and nothing after it. Table-driven, one step an op.
pub(super) fn qoi(data: &[u8], pixels: usize) -> Result<(), WalkError> {
    let ops = data.get(QOI_HEADER..).ok_or("shorter than its header")?;
    let body = ops.len().checked_sub(QOI_END.len()).ok_or("no end marker")?;
    if ops[body..] != QOI_END {
        return Err("does not end with the end marker".into());
    }
    let ops = &ops[..body];
    let (len, px) = (&QOI_OPS.0, &QOI_OPS.1);
    // At most 62 pixels a byte: no overflow, and the count is judged once.
    let (mut at, mut count) = (0usize, 0usize);
    while let Some(&op) = ops.get(at) {
        let step = usize::from(len[usize::from(op)]);
        if step == 0 {
            return Err(format!("an RGBA op at byte {} of an RGB image", QOI_HEADER + at));
        }
        at += step;
        count += usize::from(px[usize::from(op)]);
    }
    if at != ops.len() {
        return Err("an op cut short by the end marker".into());
    }
    if count != pixels {
        return Err(format!("{count} pixels, {pixels} expected"));
    }
    Ok(())
}

/// Walks an LZ4 block that must decompress to exactly `len` bytes: every
/// literal run inside the input, every match at an offset of 1 up to the
/// bytes produced so far, the last sequence literals only.
pub(super) fn lz4(data: &[u8], len: usize) -> Result<(), WalkError> {
    let (mut at, mut out) = (0usize, 0usize);
    let byte = |at: &mut usize| -> Result<usize, WalkError> {
        let b = *data.get(*at).ok_or("cut short")?;
        *at += 1;
        Ok(usize::from(b))
    };
    // A 4-bit length of 15 goes on in bytes until one is below 255.
    let extended = |at: &mut usize, mut n: usize| -> Result<usize, WalkError> {
        if n == 15 {
            loop {
                let b = byte(at)?;
                n += b;
                if b != 255 {
                    break;
                }
            }
        }
        Ok(n)
    };
    loop {
        let token = byte(&mut at)?;
        let literals = extended(&mut at, token >> 4)?;
        if literals > data.len() - at || literals > len - out {
            return Err(format!("{literals} literal bytes at byte {at} run past the end"));
        }
        at += literals;
        out += literals;
        if at == data.len() {
            break;
        }
        let offset = byte(&mut at)? | byte(&mut at)? << 8;
        if offset == 0 || offset > out {
            return Err(format!("a match {offset} bytes back, {out} bytes out"));
        }
        let matched = extended(&mut at, token & 15)? + 4;
        if matched > len - out {
            return Err(format!("a match of {matched} bytes runs past the {len}-byte tile"));
        }
        out += matched;
    }
    if out != len {
        return Err(format!("{out} bytes, {len} expected"));
    }
    Ok(())
}
