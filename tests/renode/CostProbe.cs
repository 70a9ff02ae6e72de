//
// Counts what the firmware itself (the `cargo fw` ELF) executes on Renode's Cortex-M7, for
// the step path's instructions per step and the masked spans that can delay the DIR
// interrupt (scripts/step-cost, tests/tests/renode_cost.rs). Not a chip peripheral: a probe
// on the CPU, as the DWT and a trace port would be on the NUCLEO.
//
// While armed (`Start`), a block-begin hook sees every translated block the CPU executes
// (its address and its number of instructions) and reads the CPU's state before it: IPSR
// (the active exception: which handler, nesting included, the instructions belong to),
// PRIMASK and BASEPRI. Per exception it counts instructions and entries (a block at the
// handler's address from the vector table), and per (exception, block address) the
// instructions, which the harness symbolises from the ELF (where they go, per function).
//
// Masked spans: a span is a run of blocks during which the DIR interrupt (TIM13, NVIC line
// `DirIrq`) cannot be taken: PRIMASK set, or BASEPRI non-zero and at or above (numerically
// at most) TIM13's priority, read from the NVIC at `Start`. Its length is the instructions
// of those blocks, its opener the block executed just before (the one that masked), and
// its context the exception active then. A block is the unit: the instructions of a block
// that unmasks in its middle count as masked (an upper bound on the instructions, a lower
// bound on the cycles: an instruction takes at least a cycle on the M7 at the same clock).
// "Busy" spans are runs at an execution priority that holds TIM13 off as well (handlers at
// or above its priority, TIM13's own runs included).
//
// DIR lateness: the DIR pins (`WatchDir`) are watched; at each change made inside TIM13's
// handler, TIM13's counter minus its compare (CCR1), in ticks of the step clock model.
//
// `Dump(path)` writes what was counted since `Start` as lines the harness parses:
//   dirprio P              TIM13's priority byte
//   executed N             the CPU's own count of instructions between Start and Stop
//   exc N INSTR ENTRIES P  per exception number N (0 thread mode), its priority byte
//   blk N PC INSTR         instructions per exception and block address
//   span LEN OPENER CTX K  the longest span per opener block (K: p PRIMASK, b BASEPRI)
//   in OPENER PC INSTR     the blocks inside that longest span, per opener
//   busy N LEN             the longest busy run per exception
//   dir LATE INSTR         per DIR change in TIM13: ticks late, instructions since entry
//
using System;
using System.Collections.Generic;
using System.IO;
using Antmicro.Renode.Core;
using Antmicro.Renode.Exceptions;
using Antmicro.Renode.Peripherals.Bus;
using Antmicro.Renode.Peripherals.CPU;

namespace Antmicro.Renode.Peripherals.Miscellaneous
{
    public class CostProbe : IDoubleWordPeripheral, IKnownSize, IGPIOReceiver
    {
        public CostProbe(IMachine machine)
        {
            this.machine = machine;
        }

        /// NVIC line of the DIR interrupt (TIM8_UP_TIM13: 44).
        public int DirIrq { get; set; } = 44;

        /// TIM13's base address (CNT at +0x24, CCR1 at +0x34).
        public ulong DirTimer { get; set; } = 0x40001C00;

        /// Connects pin `pin` of GPIO port `port` as a DIR line, beside what it drives.
        public void WatchDir(string port, int pin)
        {
            if(!machine.TryGetByName<INumberedGPIOOutput>(port, out var peripheral))
            {
                throw new RecoverableException($"no GPIO output peripheral named {port}");
            }
            peripheral.Connections[pin].Connect(this, pin);
        }

        /// Arms the probe: clears the counts and hooks every block the CPU executes.
        public void Start()
        {
            cpu = null;
            foreach(var c in machine.SystemBus.GetCPUs())
            {
                cpu = c as CortexM;
                if(cpu != null)
                {
                    break;
                }
            }
            if(cpu == null)
            {
                throw new RecoverableException("no Cortex-M CPU");
            }
            exc.Clear(); blocks.Clear(); spans.Clear(); spanInside.Clear(); busy.Clear(); dirs.Clear(); handlers.Clear();
            for(var n = 0u; n < prio.Length; n++)
            {
                prio[n] = n < 16 ? 0 : machine.SystemBus.ReadByte(0xE000E400 + (n - 16));
            }
            dirPrio = Priority((uint)(16 + DirIrq));
            var vtor = cpu.VectorTableOffset;
            for(var n = 1u; n < 16 + 160; n++)
            {
                handlers[n] = machine.SystemBus.ReadDoubleWord(vtor + 4 * n) & ~1u;
            }
            inSpan = false; inBusy = false; lastPc = 0; lastIpsr = 0; sinceDirEntry = 0;
            executedAtStart = cpu.ExecutedInstructions;
            executedAtStop = executedAtStart;
            cpu.SetHookAtBlockBegin(OnBlock);
            armed = true;
        }

        /// Disarms the probe (the counts stay for `Dump`).
        public void Stop()
        {
            if(cpu != null)
            {
                cpu.SetHookAtBlockBegin(null);
                executedAtStop = cpu.ExecutedInstructions;
            }
            armed = false;
        }

        /// Writes the counts (see the header) to `path`.
        public void Dump(string path)
        {
            lock(sync)
            {
                using(var w = new StreamWriter(path, false))
                {
                    w.Write($"dirprio {dirPrio}\n");
                    w.Write($"executed {executedAtStop - executedAtStart}\n");
                    foreach(var e in exc)
                    {
                        w.Write($"exc {e.Key} {e.Value[0]} {e.Value[1]} {Priority(e.Key)}\n");
                    }
                    foreach(var b in blocks)
                    {
                        w.Write($"blk {b.Key >> 32} 0x{b.Key & 0xFFFFFFFF:x} {b.Value}\n");
                    }
                    foreach(var s in spans)
                    {
                        w.Write($"span {s.Value.Item1} 0x{s.Key:x} {s.Value.Item2} {s.Value.Item3}\n");
                    }
                    foreach(var s in spanInside)
                    {
                        foreach(var b in s.Value)
                        {
                            w.Write($"in 0x{s.Key:x} 0x{b.Key:x} {b.Value}\n");
                        }
                    }
                    foreach(var b in busy)
                    {
                        w.Write($"busy {b.Key} {b.Value}\n");
                    }
                    foreach(var d in dirs)
                    {
                        w.Write($"dir {d.Item1} {d.Item2}\n");
                    }
                }
            }
        }

        private void OnBlock(ulong pc, uint size)
        {
            var ipsr = (uint)cpu.XProgramStatusRegister & 0x1FF;
            var primask = cpu.PRIMASK.RawValue & 1;
            var basepri = cpu.BasePri.RawValue & 0xFF;
            lock(sync)
            {
                if(!exc.TryGetValue(ipsr, out var e))
                {
                    e = new ulong[2];
                    exc[ipsr] = e;
                }
                e[0] += size;
                if(ipsr != 0 && handlers.TryGetValue(ipsr, out var h) && h == (pc & ~1ul))
                {
                    e[1]++;
                    if(ipsr == (uint)(16 + DirIrq))
                    {
                        sinceDirEntry = 0;
                    }
                }
                if(ipsr == (uint)(16 + DirIrq))
                {
                    sinceDirEntry += size;
                }
                var key = ((ulong)ipsr << 32) | (pc & 0xFFFFFFFF);
                blocks.TryGetValue(key, out var n);
                blocks[key] = n + size;

                var masked = primask != 0 || (basepri != 0 && basepri <= (ulong)dirPrio);
                if(masked)
                {
                    if(!inSpan)
                    {
                        inSpan = true;
                        spanLen = 0;
                        spanOpener = lastPc;
                        spanCtx = lastIpsr;
                        spanKind = primask != 0 ? "p" : "b";
                        spanBlocks = new Dictionary<ulong, ulong>();
                    }
                    spanLen += size;
                    spanBlocks.TryGetValue(pc & 0xFFFFFFFF, out var inside);
                    spanBlocks[pc & 0xFFFFFFFF] = inside + size;
                }
                else if(inSpan)
                {
                    inSpan = false;
                    if(!spans.TryGetValue(spanOpener, out var old) || old.Item1 < spanLen)
                    {
                        spans[spanOpener] = Tuple.Create(spanLen, spanCtx, spanKind);
                        spanInside[spanOpener] = spanBlocks;
                    }
                }

                var holdsDir = ipsr >= 16 && Priority(ipsr) <= dirPrio;
                if(holdsDir)
                {
                    if(!inBusy || busyIpsr != ipsr)
                    {
                        inBusy = true;
                        busyIpsr = ipsr;
                        busyLen = 0;
                    }
                    busyLen += size;
                    busy.TryGetValue(ipsr, out var longest);
                    if(busyLen > longest)
                    {
                        busy[ipsr] = busyLen;
                    }
                }
                else
                {
                    inBusy = false;
                }
                lastPc = pc & 0xFFFFFFFF;
                lastIpsr = ipsr;
            }
        }

        public void OnGPIO(int number, bool value)
        {
            if(!armed || cpu == null || !cpu.OnPossessedThread)
            {
                return;
            }
            var ipsr = (uint)cpu.XProgramStatusRegister & 0x1FF;
            if(ipsr != (uint)(16 + DirIrq))
            {
                return;
            }
            var cnt = machine.SystemBus.ReadDoubleWord(DirTimer + 0x24);
            var ccr = machine.SystemBus.ReadDoubleWord(DirTimer + 0x34);
            lock(sync)
            {
                dirs.Add(Tuple.Create((cnt - ccr) & 0xFFFF, sinceDirEntry));
            }
        }

        /// The priority byte of exception `n` (system exceptions below 16 count as 0: above
        /// every configurable one, as HardFault and NMI are; SVCall and PendSV are not used
        /// by the firmware).
        private int Priority(uint n)
        {
            return n < prio.Length ? prio[n] : 0;
        }

        public void Reset()
        {
        }

        public long Size => 0x10;

        public uint ReadDoubleWord(long offset) => armed ? 1u : 0u;

        public void WriteDoubleWord(long offset, uint value)
        {
        }

        private readonly IMachine machine;
        private readonly object sync = new object();
        private CortexM cpu;
        private bool armed;
        private ulong executedAtStart, executedAtStop;
        private int dirPrio;
        // Priority bytes per exception number, read from the NVIC at Start.
        private readonly int[] prio = new int[16 + 160];
        private readonly Dictionary<uint, ulong[]> exc = new Dictionary<uint, ulong[]>();
        private readonly Dictionary<ulong, ulong> blocks = new Dictionary<ulong, ulong>();
        private readonly Dictionary<ulong, Tuple<ulong, uint, string>> spans = new Dictionary<ulong, Tuple<ulong, uint, string>>();
        // Per opener: the blocks of its longest span and their instructions.
        private readonly Dictionary<ulong, Dictionary<ulong, ulong>> spanInside = new Dictionary<ulong, Dictionary<ulong, ulong>>();
        private Dictionary<ulong, ulong> spanBlocks = new Dictionary<ulong, ulong>();
        private readonly Dictionary<uint, ulong> busy = new Dictionary<uint, ulong>();
        private readonly List<Tuple<uint, ulong>> dirs = new List<Tuple<uint, ulong>>();
        private readonly Dictionary<uint, uint> handlers = new Dictionary<uint, uint>();
        private bool inSpan, inBusy;
        private ulong spanLen, spanOpener, lastPc, busyLen, sinceDirEntry;
        private uint spanCtx, lastIpsr, busyIpsr;
        private string spanKind;
    }
}
