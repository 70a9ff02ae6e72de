//
// The Cortex-M7's DWT cycle counter (ARMv7-M Architecture Reference Manual, C1.8 "The Data
// Watchpoint and Trace unit": DWT_CTRL at 0xE0001000, DWT_CYCCNT at 0xE0001004; the lock
// access register at 0xE0001FB0) for Renode 1.15.3, whose STM32H743 has no DWT (reads of an
// unmapped region give 0). The firmware stamps its critical sections with CYCCNT for the
// DIAG report (issue 34, firmware/board/src/diag.rs): without a counter every masked span
// read 0 cycles on Renode.
//
// CYCCNT counts the CPU clock (Frequency, 400 MHz by default) from virtual time, brought up
// to date before each read as the step models do: at `PerformanceInMips 400` that is one
// count per instruction, the emulator's figure, not the chip's (no pipeline, no bus or
// flash waits). Counting runs while CTRL.CYCCNTENA is set; a write to CYCCNT sets it. The
// comparators, the other counters and the lock (always open here) are not modelled.
//
using System;
using Antmicro.Renode.Core;
using Antmicro.Renode.Logging;
using Antmicro.Renode.Peripherals.Bus;

namespace Antmicro.Renode.Peripherals.Miscellaneous
{
    public class CortexM7_DWT : IDoubleWordPeripheral, IKnownSize
    {
        public CortexM7_DWT(IMachine machine, long frequency = 400000000)
        {
            this.machine = machine;
            this.frequency = frequency;
            Reset();
        }

        public long Size => 0x1000;

        public void Reset()
        {
            enabled = false;
            frozen = 0;
            anchorNs = 0;
        }

        public uint ReadDoubleWord(long offset)
        {
            switch(offset)
            {
            case Ctrl:
                // NUMCOMP 0, the cycle counter present (NOCYCCNT clear), CYCCNTENA.
                return enabled ? CtrlCycCntEna : 0u;
            case CycCnt:
                return Count();
            default:
                return 0;
            }
        }

        public void WriteDoubleWord(long offset, uint value)
        {
            switch(offset)
            {
            case Ctrl:
                var enable = (value & CtrlCycCntEna) != 0;
                if(enable != enabled)
                {
                    // Keep the count across a stop and a restart.
                    frozen = Count();
                    anchorNs = NowNs();
                    enabled = enable;
                }
                break;
            case CycCnt:
                frozen = value;
                anchorNs = NowNs();
                break;
            default:
                // The lock access register and the rest: accepted, ignored.
                break;
            }
        }

        private uint Count()
        {
            if(!enabled)
            {
                return frozen;
            }
            var elapsed = (decimal)(NowNs() - anchorNs) * frequency / 1000000000m;
            return unchecked(frozen + (uint)((ulong)Math.Floor(elapsed) & 0xFFFFFFFF));
        }

        private long NowNs()
        {
            // The CPU may have executed instructions it has not reported yet (see the step
            // models): report them, so that the read happens at its own instruction's time.
            if(machine.SystemBus.TryGetCurrentCPU(out var cpu) && cpu.OnPossessedThread)
            {
                cpu.SyncTime();
            }
            return (long)machine.ClockSource.CurrentValue.Ticks;
        }

        private readonly IMachine machine;
        private readonly long frequency;
        private bool enabled;
        private uint frozen;
        private long anchorNs;

        private const long Ctrl = 0x0;
        private const long CycCnt = 0x4;
        private const uint CtrlCycCntEna = 1u;
    }
}
