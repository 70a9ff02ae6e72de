//! A self-check of the run-time routines the boards link (compiler-builtins' `memcpy`,
//! `memmove`, `memset`, `memcmp`, their ARM EABI entry points and `__aeabi_uldivmod`; until
//! issue 20 this crate had hand-written assembly versions for flash) against byte-by-byte
//! and bit-by-bit models, on the target itself: the QEMU board runs it when
//! its command line asks (`-append check-runtime`, tests/tests/qemu.rs). Nothing calls it
//! on the NUCLEO board, so it costs that image nothing.
//!
//! Every alignment of both pointers (0..8) and length up to 80 for `memcpy` and `memset`
//! (and their EABI forms), every overlap of source and destination within 72 bytes in
//! both directions for `memmove`, every length up to 40 with and without a differing
//! byte for `memcmp`, and edge values plus pseudo-random operands of every bit length for
//! u64 `/` and `%`.

use core::hint::black_box;
use core::ptr::{read_volatile, write_volatile};

unsafe extern "C" {
    fn memcpy(dst: *mut u8, src: *const u8, n: usize) -> *mut u8;
    fn memmove(dst: *mut u8, src: *const u8, n: usize) -> *mut u8;
    fn memset(dst: *mut u8, byte: i32, n: usize) -> *mut u8;
    fn memcmp(a: *const u8, b: *const u8, n: usize) -> i32;
    fn __aeabi_memcpy4(dst: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memmove8(dst: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memset(dst: *mut u8, n: usize, byte: i32);
    fn __aeabi_memclr(dst: *mut u8, n: usize);
}

/// Bytes in each test buffer: the largest offset plus the largest length, with margin.
const BUFFER: usize = 200;

/// What the check found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Outcome {
    /// Cases compared with their model.
    pub cases: u32,
    /// Cases whose result differed from the model's.
    pub failures: u32,
}

impl Outcome {
    fn record(&mut self, ok: bool) {
        self.cases += 1;
        if !ok {
            self.failures += 1;
        }
    }
}

/// A test buffer, read and written through volatile accesses so that the models are not
/// turned into calls of the routines under test.
#[repr(C, align(8))]
struct Bytes([u8; BUFFER]);

impl Bytes {
    fn ptr(&mut self) -> *mut u8 {
        self.0.as_mut_ptr()
    }

    fn get(&mut self, i: usize) -> u8 {
        // SAFETY: every caller's index is below BUFFER (offsets < 80, lengths <= 80).
        unsafe { read_volatile(self.ptr().add(i)) }
    }

    fn set(&mut self, i: usize, value: u8) {
        // SAFETY: as in `get`.
        unsafe { write_volatile(self.ptr().add(i), value) }
    }

    /// Pseudo-random contents from `seed`.
    fn fill(&mut self, seed: u32) {
        let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        for i in 0..BUFFER {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            self.set(i, x.to_le_bytes()[0]);
        }
    }

    fn snapshot(&mut self) -> [u8; BUFFER] {
        let mut copy = [0; BUFFER];
        for (i, byte) in copy.iter_mut().enumerate() {
            *byte = self.get(i);
        }
        copy
    }

    fn equals(&mut self, expected: &[u8; BUFFER]) -> bool {
        expected
            .iter()
            .enumerate()
            .all(|(i, &byte)| self.get(i) == byte)
    }
}

/// A buffer's fill seed from a case's figures.
fn seed(value: usize) -> u32 {
    u32::try_from(value).unwrap_or(u32::MAX)
}

/// Runs every case; returns how many there were and how many failed.
pub fn check() -> Outcome {
    let mut outcome = Outcome::default();
    let mut a = Bytes([0; BUFFER]);
    let mut b = Bytes([0; BUFFER]);
    check_copy(&mut outcome, &mut a, &mut b);
    check_move(&mut outcome, &mut a);
    check_set(&mut outcome, &mut a);
    check_compare(&mut outcome, &mut a, &mut b);
    check_division(&mut outcome);
    outcome
}

fn check_copy(outcome: &mut Outcome, a: &mut Bytes, b: &mut Bytes) {
    for from in 0..8 {
        for to in 0..8 {
            for n in 0..=80 {
                for eabi in [false, true] {
                    a.fill(seed(from * 1000 + to * 100 + n));
                    b.fill(seed(77 + n));
                    let mut expected = b.snapshot();
                    for (i, byte) in expected.iter_mut().skip(to).take(n).enumerate() {
                        *byte = a.get(from + i);
                    }
                    // SAFETY: from/to + n <= 87 < BUFFER; the buffers do not overlap.
                    let returned = unsafe {
                        if eabi && from % 4 == 0 && to % 4 == 0 {
                            __aeabi_memcpy4(b.ptr().add(to), a.ptr().add(from), n);
                            b.ptr().add(to)
                        } else {
                            memcpy(b.ptr().add(to), a.ptr().add(from), n)
                        }
                    };
                    // SAFETY: in bounds, as above.
                    let ok = returned == unsafe { b.ptr().add(to) } && b.equals(&expected);
                    outcome.record(ok);
                }
            }
        }
    }
}

fn check_move(outcome: &mut Outcome, a: &mut Bytes) {
    const LENGTHS: [usize; 18] = [
        0, 1, 2, 3, 4, 5, 7, 8, 9, 12, 15, 16, 17, 31, 32, 33, 63, 64,
    ];
    for from in 0..=72 {
        for to in 0..=72 {
            for n in LENGTHS {
                for eabi in [false, true] {
                    a.fill(seed(from * 7 + to * 13 + n));
                    let original = a.snapshot();
                    let mut expected = original;
                    for (i, byte) in expected.iter_mut().skip(to).take(n).enumerate() {
                        *byte = original.get(from + i).copied().unwrap_or_default();
                    }
                    // SAFETY: from/to + n <= 136 < BUFFER; memmove allows the overlap.
                    let returned = unsafe {
                        if eabi {
                            __aeabi_memmove8(a.ptr().add(to), a.ptr().add(from), n);
                            a.ptr().add(to)
                        } else {
                            memmove(a.ptr().add(to), a.ptr().add(from), n)
                        }
                    };
                    // SAFETY: in bounds, as above.
                    let ok = returned == unsafe { a.ptr().add(to) } && a.equals(&expected);
                    outcome.record(ok);
                }
            }
        }
    }
}

fn check_set(outcome: &mut Outcome, a: &mut Bytes) {
    for to in 0..8 {
        for n in 0..=80 {
            for form in 0..3 {
                a.fill(seed(to * 100 + n));
                let mut expected = a.snapshot();
                let value: u8 = match form {
                    0 => 0xA5,
                    1 => 0x5A,
                    _ => 0,
                };
                for byte in expected.iter_mut().skip(to).take(n) {
                    *byte = value;
                }
                // SAFETY: to + n <= 87 < BUFFER.
                let returned_ok = unsafe {
                    let dst = a.ptr().add(to);
                    match form {
                        // Only the low byte of the int counts.
                        0 => memset(dst, 0x1A5, n) == dst,
                        1 => {
                            __aeabi_memset(dst, n, 0x5A);
                            true
                        }
                        _ => {
                            __aeabi_memclr(dst, n);
                            true
                        }
                    }
                };
                let ok = returned_ok && a.equals(&expected);
                outcome.record(ok);
            }
        }
    }
}

fn check_compare(outcome: &mut Outcome, a: &mut Bytes, b: &mut Bytes) {
    for from in 0..4 {
        for to in 0..4 {
            for n in 0..=40 {
                for differ_at in 0..=n {
                    a.fill(seed(from + to * 5 + n));
                    for i in 0..n {
                        let byte = a.get(from + i);
                        b.set(to + i, byte);
                    }
                    let mut expected = 0;
                    if differ_at < n {
                        let x = a.get(from + differ_at);
                        let y = x.wrapping_add(if (n + differ_at) % 2 == 0 { 1 } else { 255 });
                        b.set(to + differ_at, y);
                        expected = if x > y { 1 } else { -1 };
                    }
                    // SAFETY: from/to + n <= 43 < BUFFER.
                    let got = unsafe { memcmp(a.ptr().add(from), b.ptr().add(to), n) };
                    outcome.record(got.signum() == expected);
                }
            }
        }
    }
}

/// Quotient and remainder by shifts and subtractions only (no division to call).
fn divide_model(n: u64, d: u64) -> (u64, u64) {
    let mut quotient = 0u64;
    let mut remainder = 0u128;
    for bit in (0..64).rev() {
        remainder = (remainder << 1) | u128::from((n >> bit) & 1);
        if remainder >= u128::from(d) {
            remainder -= u128::from(d);
            quotient |= 1 << bit;
        }
    }
    (quotient, u64::try_from(remainder).unwrap_or(u64::MAX))
}

fn check_division(outcome: &mut Outcome) {
    const EDGES: [u64; 16] = [
        0,
        1,
        2,
        3,
        7,
        1000,
        0x7fff_ffff,
        0x8000_0000,
        0xffff_ffff,
        0x1_0000_0000,
        0x1_0000_0001,
        0xdead_beef_cafe,
        1 << 62,
        1 << 63,
        u64::MAX - 1,
        u64::MAX,
    ];
    let mut case = |n: u64, d: u64| {
        if d == 0 {
            return;
        }
        let got = (black_box(n) / black_box(d), black_box(n) % black_box(d));
        outcome.record(got == divide_model(n, d));
    };
    for n in EDGES {
        for d in EDGES {
            case(n, d);
        }
    }
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for _ in 0..50_000 {
        let (a, b, c) = (next(), next(), next());
        case(a >> (c & 63), b >> ((c >> 8) & 63));
    }
}
