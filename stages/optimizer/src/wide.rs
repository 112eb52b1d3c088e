//! The optimizers' hottest loops built a second time for AVX2, chosen at run time.
//!
//! The binary targets plain x86-64, so the compiler vectorises those loops (column `axpy`s over
//! contiguous `f64`) two lanes wide with SSE2. The same source compiled inside a function with AVX2
//! enabled runs four lanes wide. The arithmetic is the same: each lane does the one multiply and the
//! one add or subtract the source asks for, in the source's order (Rust never fuses a multiply and
//! an add on its own), so both builds give the same bits, which the callers' tests check.

/// Whether this CPU runs the AVX2 builds (std caches the detection).
pub fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Defines `pub fn $name($args) -> $ret` that runs `$body` (an `#[inline(always)]` function with
/// the same arguments) compiled for AVX2 when [`avx2`] holds, and as built otherwise.
macro_rules! with_avx2 {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),*) -> $ret:ty = $body:ident;) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2")]
                fn wide($($arg: $ty),*) -> $ret {
                    $body($($arg),*)
                }
                if $crate::wide::avx2() {
                    // SAFETY: `wide` is unsafe to call only because it is compiled for AVX2,
                    // which this CPU was just found to have.
                    return unsafe { wide($($arg),*) };
                }
            }
            $body($($arg),*)
        }
    };
}
pub(crate) use with_avx2;
