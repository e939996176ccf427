//! Fallible allocation of the buffers whose size is a product of input sizes: the Jacobian (samples
//! × parameters of the utterance's phonemes) and the walker batches (walkers × samples). Rust
//! aborts the whole process when an allocation fails; a Python user who asks for a Jacobian of a
//! 20 000-phoneme utterance must get a `MemoryError` naming the sizes instead, and keep the
//! interpreter. Buffers proportional to one input array are left to the ordinary allocator: the
//! caller already holds an array of that size.

use crate::error::ModelError;

/// `Vec::with_capacity(n)`, or [`ModelError::OutOfMemory`] naming `what` (called only on
/// failure, to describe the buffer and the sizes it is the product of).
pub fn try_with_capacity<T>(n: usize, what: impl FnOnce() -> String) -> Result<Vec<T>, ModelError> {
    let mut v = Vec::new();
    match v.try_reserve_exact(n) {
        Ok(()) => Ok(v),
        Err(_) => Err(out_of_memory::<T>(n as u128, what())),
    }
}

/// `vec![value; n]`, or [`ModelError::OutOfMemory`] as [`try_with_capacity`].
pub fn try_filled<T: Clone>(
    n: usize,
    value: T,
    what: impl FnOnce() -> String,
) -> Result<Vec<T>, ModelError> {
    let mut v = try_with_capacity(n, what)?;
    v.resize(n, value);
    Ok(v)
}

/// a × b elements of `T`, or [`ModelError::OutOfMemory`] when the product does not even fit in
/// the address space.
pub fn product<T>(a: usize, b: usize, what: impl FnOnce() -> String) -> Result<usize, ModelError> {
    a.checked_mul(b)
        .filter(|&n| n.checked_mul(std::mem::size_of::<T>()).is_some())
        .ok_or_else(|| out_of_memory::<T>(a as u128 * b as u128, what()))
}

fn out_of_memory<T>(elements: u128, what: String) -> ModelError {
    ModelError::OutOfMemory {
        what,
        elements,
        element_bytes: std::mem::size_of::<T>(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn impossible_sizes_are_errors_naming_the_buffer() {
        let e = try_with_capacity::<f64>(usize::MAX / 4, || "a test buffer".into()).unwrap_err();
        assert!(e.is_out_of_memory());
        let msg = e.to_string();
        assert!(msg.starts_with("cannot allocate a test buffer: "), "{msg}");
        assert!(
            msg.contains(&format!("{} values of 8 bytes", usize::MAX / 4)),
            "{msg}"
        );
        let e = product::<f64>(usize::MAX / 2, 3, || "walkers × samples".into()).unwrap_err();
        assert!(
            matches!(e, ModelError::OutOfMemory { elements, .. } if elements == (usize::MAX / 2) as u128 * 3)
        );
        assert_eq!(product::<f64>(1000, 3, || unreachable!()).unwrap(), 3000);
        assert_eq!(try_filled(3, 1.5, || unreachable!()).unwrap(), vec![1.5; 3]);
    }
}
