//! What the firmware itself executes on Renode, from the CPU probe
//! (`tests/renode/CostProbe.cs`, included by `tests/renode/cost-probe.resc`): instructions
//! per exception (nesting included: the probe reads IPSR before every block), per function
//! (symbolised here from the ELF's symbol table), the spans that mask the DIR interrupt with
//! the function that opened them, and TIM13's counter minus its compare at each DIR write.
//! `tests/tests/renode_cost.rs` and `scripts/step-cost/run.sh` print them.

use std::collections::HashMap;
use std::path::Path;

/// Exception numbers (IPSR) of the board's step path: TIM13 (IRQ 44), the step service
/// (TIM7's vector, IRQ 55), the step streams (`firmware/board/src/step_dma/refill.rs`
/// `STREAM_IRQS`: joints 0-3 on DMA1 streams 0-3, IRQ 11-14; joints 4-7 on DMA2 streams
/// 0-3, IRQ 56-59, since issue 34 split them by timer bus).
pub const TIM13: u32 = 16 + 44;
/// The step service's exception number (TIM7's vector).
pub const STEP_SERVICE: u32 = 16 + 55;
/// The step streams' exception numbers, joint 0 first: DMA1 streams 0-3, DMA2 streams 0-3.
/// (Until the split every joint was on DMA2; counting DMA2 alone after it left joints 0-3's
/// refills out of the figures: 20 instructions per step instead of 35-49.)
pub const STEP_STREAMS: [u32; 8] = [27, 28, 29, 30, 72, 73, 74, 75];

/// Every exception the step path's interrupts run in.
pub fn step_path_exceptions() -> impl Iterator<Item = u32> {
    [TIM13, STEP_SERVICE].into_iter().chain(STEP_STREAMS)
}

/// A name for an exception number.
pub fn exception_name(n: u32) -> String {
    match n {
        0 => "thread mode".into(),
        TIM13 => "TIM8_UP_TIM13 (DIR, step clock)".into(),
        STEP_SERVICE => "TIM7 (step service)".into(),
        22 => "EXTI0 (e-stop input)".into(),
        59 => "TIM8_BRK_TIM12 (embassy-time)".into(),
        77 => "ETH".into(),
        n if STEP_STREAMS.contains(&n) => {
            let joint = STEP_STREAMS.iter().position(|&s| s == n).unwrap_or(0);
            format!(
                "DMA{}_STREAM{} (refill, joint {joint})",
                1 + joint / 4,
                joint % 4
            )
        }
        n if n >= 16 => format!("IRQ {}", n - 16),
        n => format!("exception {n}"),
    }
}

/// A masked span: the longest the probe saw after one opener block.
#[derive(Debug, Clone)]
pub struct Span {
    /// Instructions while masked.
    pub instructions: u64,
    /// The block executed just before masking (the one that masked).
    pub opener: u32,
    /// The exception active then (0 thread mode).
    pub context: u32,
    /// PRIMASK (`true`) or BASEPRI at or above TIM13's priority.
    pub primask: bool,
}

/// What the probe counted between its `Start` and its `Dump`.
#[derive(Debug, Default)]
pub struct Counts {
    /// TIM13's priority byte in the NVIC.
    pub dir_priority: u8,
    /// The CPU's own count of instructions executed while the probe was armed (Renode's
    /// `ExecutedInstructions`): the check that the probe's block sizes are instructions.
    pub executed: u64,
    /// Per exception number: instructions, entries, priority byte.
    pub exceptions: HashMap<u32, (u64, u64, u8)>,
    /// (exception, block address) -> instructions.
    pub blocks: Vec<(u32, u32, u64)>,
    /// The longest span per opener.
    pub spans: Vec<Span>,
    /// Per opener: the blocks inside its longest span (block address, instructions).
    pub inside: HashMap<u32, Vec<(u32, u64)>>,
    /// Per exception at or above TIM13's priority, its longest run.
    pub busy: HashMap<u32, u64>,
    /// Per DIR change inside TIM13: its counter minus its compare (ticks of the model's
    /// clock), and TIM13's instructions since its entry.
    pub dirs: Vec<(u32, u64)>,
}

impl Counts {
    /// Parses the probe's dump (`CostProbe.cs`'s header).
    pub fn parse(text: &str) -> Counts {
        let mut counts = Counts::default();
        let hex = |s: &str| u32::from_str_radix(s.trim_start_matches("0x"), 16).unwrap_or(0);
        for line in text.lines() {
            let f: Vec<&str> = line.split_whitespace().collect();
            let num = |i: usize| f.get(i).and_then(|s| s.parse::<u64>().ok()).unwrap_or(0);
            match f.first().copied() {
                Some("dirprio") => counts.dir_priority = num(1) as u8,
                Some("executed") => counts.executed = num(1),
                Some("exc") => {
                    counts
                        .exceptions
                        .insert(num(1) as u32, (num(2), num(3), num(4) as u8));
                }
                Some("blk") if f.len() == 4 => {
                    counts.blocks.push((num(1) as u32, hex(f[2]), num(3)));
                }
                Some("span") if f.len() == 5 => counts.spans.push(Span {
                    instructions: num(1),
                    opener: hex(f[2]),
                    context: num(3) as u32,
                    primask: f[4] == "p",
                }),
                Some("in") if f.len() == 4 => {
                    counts
                        .inside
                        .entry(hex(f[1]))
                        .or_default()
                        .push((hex(f[2]), num(3)));
                }
                Some("busy") => {
                    counts.busy.insert(num(1) as u32, num(2));
                }
                Some("dir") => counts.dirs.push((num(1) as u32, num(2))),
                _ => {}
            }
        }
        counts
    }

    /// Instructions executed in exception `n`.
    pub fn instructions(&self, n: u32) -> u64 {
        self.exceptions.get(&n).map_or(0, |e| e.0)
    }

    /// Times exception `n` was entered.
    pub fn entries(&self, n: u32) -> u64 {
        self.exceptions.get(&n).map_or(0, |e| e.1)
    }

    /// Instructions the probe counted, all exceptions and thread mode.
    pub fn total(&self) -> u64 {
        self.exceptions.values().map(|e| e.0).sum()
    }

    /// Instructions of the step path's interrupts (TIM13, the service, DMA2's streams).
    pub fn step_path_interrupts(&self) -> u64 {
        step_path_exceptions().map(|n| self.instructions(n)).sum()
    }

    /// Instructions per function (symbolised) in the exceptions `filter` accepts, most first.
    pub fn per_function(
        &self,
        symbols: &Symbols,
        filter: impl Fn(u32) -> bool,
    ) -> Vec<(String, u64)> {
        let mut by: HashMap<String, u64> = HashMap::new();
        for &(n, pc, count) in &self.blocks {
            if filter(n) {
                *by.entry(symbols.name(pc)).or_default() += count;
            }
        }
        let mut list: Vec<_> = by.into_iter().collect();
        list.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        list
    }

    /// The functions inside the longest span opened by `opener`, most instructions first.
    pub fn inside(&self, symbols: &Symbols, opener: u32) -> Vec<(String, u64)> {
        let mut by: HashMap<String, u64> = HashMap::new();
        for &(pc, count) in self.inside.get(&opener).into_iter().flatten() {
            *by.entry(symbols.name(pc)).or_default() += count;
        }
        let mut list: Vec<_> = by.into_iter().collect();
        list.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        list
    }

    /// The spans that mask the DIR interrupt, longest first.
    pub fn spans_longest_first(&self) -> Vec<Span> {
        let mut spans = self.spans.clone();
        spans.sort_by_key(|s| std::cmp::Reverse(s.instructions));
        spans
    }
}

/// The ELF's function symbols, for naming addresses.
#[derive(Debug, Default)]
pub struct Symbols {
    /// (start, size, demangled name), by start.
    functions: Vec<(u32, u32, String)>,
}

impl Symbols {
    /// Reads the function symbols (STT_FUNC) of a 32-bit little-endian ELF.
    pub fn read(path: &Path) -> Symbols {
        let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut functions = parse_functions(&bytes).unwrap_or_default();
        functions.sort_by_key(|f| f.0);
        Symbols { functions }
    }

    /// The function `pc` is in (`?0x...` if none).
    pub fn name(&self, pc: u32) -> String {
        let pc = pc & !1;
        let at = self.functions.partition_point(|f| f.0 <= pc);
        at.checked_sub(1)
            .map(|i| &self.functions[i])
            .filter(|f| pc < f.0 + f.1.max(2))
            .map_or_else(|| format!("?{pc:#x}"), |f| f.2.clone())
    }

    /// Whether any function's demangled name contains `text`.
    pub fn any_contains(&self, text: &str) -> bool {
        self.functions.iter().any(|f| f.2.contains(text))
    }
}

fn parse_functions(b: &[u8]) -> Option<Vec<(u32, u32, String)>> {
    let u16_at = |at: usize| Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?));
    let u32_at = |at: usize| Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?));
    if b.get(..6)? != b"\x7fELF\x01\x01" {
        return None;
    }
    let shoff = u32_at(0x20)? as usize;
    let shentsize = usize::from(u16_at(0x2E)?);
    let shnum = usize::from(u16_at(0x30)?);
    // (type, offset, size, link, entsize)
    let section = |i: usize| -> Option<(u32, usize, usize, usize, usize)> {
        let at = shoff + i * shentsize;
        Some((
            u32_at(at + 4)?,
            u32_at(at + 16)? as usize,
            u32_at(at + 20)? as usize,
            u32_at(at + 24)? as usize,
            u32_at(at + 36)? as usize,
        ))
    };
    let (_, symoff, symsize, strndx, entsize) =
        (0..shnum).filter_map(section).find(|s| s.0 == 2)?; // SHT_SYMTAB
    let strtab = section(strndx)?.1;
    let mut out = Vec::new();
    for k in 0..symsize / entsize.max(1) {
        let at = symoff + k * entsize;
        let info = *b.get(at + 12)?;
        if info & 0xF != 2 {
            continue; // STT_FUNC only
        }
        let start = strtab + u32_at(at)? as usize;
        let rest = b.get(start..)?;
        let end = rest.iter().position(|&c| c == 0)?;
        let name = std::str::from_utf8(&rest[..end]).ok()?;
        out.push((u32_at(at + 4)? & !1, u32_at(at + 8)?, demangle(name)));
    }
    Some(out)
}

/// Rust's legacy mangling (`_ZN` length-prefixed parts, a hash last) to a path without
/// the hash; anything else as it is.
pub fn demangle(name: &str) -> String {
    let Some(mut rest) = name.strip_prefix("_ZN") else {
        return name.to_string();
    };
    let mut parts = Vec::new();
    while let Some(digits) = rest.find(|c: char| !c.is_ascii_digit()).filter(|&d| d > 0) {
        let Ok(len) = rest[..digits].parse::<usize>() else {
            break;
        };
        let Some(part) = rest.get(digits..digits + len) else {
            break;
        };
        parts.push(part);
        rest = &rest[digits + len..];
    }
    if parts
        .last()
        .is_some_and(|p| p.len() == 17 && p.starts_with('h'))
    {
        parts.pop();
    }
    let path = parts.join("::");
    [
        ("$LT$", "<"),
        ("$GT$", ">"),
        ("$u20$", " "),
        ("$u27$", "'"),
        ("$u7b$", "{"),
        ("$u7d$", "}"),
        ("$RF$", "&"),
        ("$C$", ","),
        ("$BP$", "*"),
        ("..", "::"),
    ]
    .iter()
    .fold(path, |s, (from, to)| s.replace(from, to))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demangles_legacy_paths_without_the_hash() {
        assert_eq!(
            demangle("_ZN8firmware8step_dma6refill6refill17h0123456789abcdefE"),
            "firmware::step_dma::refill::refill"
        );
        assert_eq!(demangle("DMA2_STREAM0"), "DMA2_STREAM0");
    }

    #[test]
    fn parses_the_probes_dump() {
        let c = Counts::parse(
            "dirprio 16\nexc 60 100 5 16\nblk 60 0x8000c70 40\nspan 33 0x8000c70 60 p\nbusy 60 68\ndir 12 40\n",
        );
        assert_eq!(c.dir_priority, 16);
        assert_eq!(c.instructions(TIM13), 100);
        assert_eq!(c.entries(TIM13), 5);
        assert_eq!(c.blocks, vec![(60, 0x8000c70, 40)]);
        assert_eq!(c.spans[0].instructions, 33);
        assert!(c.spans[0].primask);
        assert_eq!(c.busy[&60], 68);
        assert_eq!(c.dirs, vec![(12, 40)]);
    }
}
