//
// IWDG1 of the STM32H743 for Renode 1.15.3 (loaded by tests/renode/nucleo-h743zi2.resc in
// place of the stock model).
//
// Follows RM0433 (Rev 7) section 45 "Independent watchdog (IWDG)": a 12-bit down-counter
// clocked by the LSI through a prescaler of 4 << PR (PR 0-6, 7 = 256), reloaded with RLR by
// the key 0xAAAA, started by 0xCCCC, registers unlocked by 0x5555; the chip resets when the
// counter reaches zero. The window (WINR) is not modelled: the firmware leaves it open.
//
// Why not the stock model: stm32h743.repl clocks it at 56 kHz, but the H7's LSI runs at
// 32 kHz (RM0433 "LSI oscillator", the datasheet's f_LSI typ. 32 kHz), so the firmware's 1 s
// watchdog reset the emulated board after 0.57 s. And after a reset Renode's machine halts
// at PC 0 (nothing maps the boot address), so a watchdog reset left no trace of where the
// firmware was stuck: this model logs, before the reset, the CPU's PC, LR, SP, the
// exception it was in (ICSR.VECTACTIVE, 0 = thread mode), the pending one (VECTPENDING) and
// the words on top of the stack (return addresses of the callers, for addr2line).
//
using System;
using System.Linq;
using System.Text;
using Antmicro.Renode.Core;
using Antmicro.Renode.Logging;
using Antmicro.Renode.Peripherals.Bus;
using Antmicro.Renode.Peripherals.CPU;
using Antmicro.Renode.Time;

namespace Antmicro.Renode.Peripherals.Timers
{
    public class STM32H7_IWDG : IDoubleWordPeripheral, IKnownSize
    {
        public STM32H7_IWDG(IMachine machine, long frequency = LsiHz)
        {
            this.machine = machine;
            counter = new LimitTimer(machine.ClockSource, frequency, this, "iwdg", limit: MaxReload,
                direction: Direction.Descending, enabled: false, workMode: WorkMode.OneShot,
                eventEnabled: true, autoUpdate: true, divider: 4);
            counter.LimitReached += OnExpired;
            Reset();
        }

        public long Size => 0x400;

        // Words the reset's log line adds, as `name=0xADDRESS` separated by spaces (the .resc
        // names the embassy time driver's timer and its NVIC bits: a task that waits on a
        // timer that never fires is the one hang the firmware cannot log itself).
        public string DumpOnReset { get; set; } = "";

        public void Reset()
        {
            counter.Reset();
            unlocked = false;
            prescaler = 0;
            reload = MaxReload;
            counter.Limit = reload;
        }

        public uint ReadDoubleWord(long offset)
        {
            switch(offset)
            {
            case Prescaler:
                return prescaler;
            case Reload:
                return reload;
            case Window:
                return MaxReload;
            default:
                // KR reads 0; SR: the prescaler and reload updates complete at once.
                return 0;
            }
        }

        public void WriteDoubleWord(long offset, uint value)
        {
            switch(offset)
            {
            case Key:
                unlocked = false;
                switch(value & 0xFFFF)
                {
                case KeyStart:
                    counter.Limit = reload;
                    counter.Enabled = true;
                    break;
                case KeyReload:
                    counter.Limit = reload;
                    break;
                case KeyUnlock:
                    unlocked = true;
                    break;
                }
                break;
            case Prescaler:
            case Reload:
                if(!unlocked)
                {
                    this.Log(LogLevel.Warning, "write of 0x{0:X} to 0x{1:X} ignored (registers locked)", value, offset);
                }
                else if(offset == Prescaler)
                {
                    prescaler = value & 0x7;
                    counter.Divider = Math.Min(4 << (int)prescaler, 256);
                }
                else
                {
                    reload = value & MaxReload;
                }
                break;
            }
        }

        private void OnExpired()
        {
            this.Log(LogLevel.Warning, "Watchdog reset triggered! {0}", WhereTheCpuWas());
            machine.RequestReset();
        }

        private string WhereTheCpuWas()
        {
            var cpu = machine.SystemBus.GetCPUs().OfType<ICPUWithRegisters>().FirstOrDefault();
            if(cpu == null)
            {
                return "(no CPU)";
            }
            var sysbus = machine.SystemBus;
            var sp = (ulong)cpu.GetRegister(13);
            var icsr = sysbus.ReadDoubleWord(IcsrAddress);
            var text = new StringBuilder();
            text.AppendFormat("PC 0x{0:X8} LR 0x{1:X8} SP 0x{2:X8} VECTACTIVE {3} VECTPENDING {4}; stack:",
                (ulong)cpu.PC, (ulong)cpu.GetRegister(14), sp, icsr & 0x1FF, (icsr >> 12) & 0x1FF);
            for(var i = 0UL; i < StackWords && sp + 4 * i < StackTop; i++)
            {
                text.AppendFormat(" {0:X8}", sysbus.ReadDoubleWord(sp + 4 * i));
            }
            text.Append(";");
            foreach(var entry in DumpOnReset.Split(new[] { ' ' }, StringSplitOptions.RemoveEmptyEntries))
            {
                var parts = entry.Split('=');
                ulong address;
                if(parts.Length == 2 && ulong.TryParse(parts[1].Replace("0x", ""), System.Globalization.NumberStyles.HexNumber, null, out address))
                {
                    text.AppendFormat(" {0} 0x{1:X8}", parts[0], sysbus.ReadDoubleWord(address));
                }
            }
            return text.ToString();
        }

        private readonly IMachine machine;
        private readonly LimitTimer counter;
        private bool unlocked;
        private uint prescaler;
        private uint reload;

        // The H7's LSI (RM0433, datasheet: 32 kHz typical).
        private const long LsiHz = 32000;
        private const uint MaxReload = 0xFFF;
        private const uint KeyStart = 0xCCCC;
        private const uint KeyReload = 0xAAAA;
        private const uint KeyUnlock = 0x5555;
        private const long Key = 0x0;
        private const long Prescaler = 0x4;
        private const long Reload = 0x8;
        private const long Window = 0x10;
        // SCB ICSR: VECTACTIVE [8:0], VECTPENDING [20:12].
        private const ulong IcsrAddress = 0xE000ED04;
        // Words of the stack logged (each a saved register or a return address).
        private const ulong StackWords = 48;
        // The stack's top: the end of DTCM (memory.x `_stack_start`).
        private const ulong StackTop = 0x20020000;
    }
}
