//
// The STM32H743's DMA1/DMA2 controllers as the arm controller's step path uses them, for
// Renode 1.15.3 (loaded at run time by tests/renode/step-path.resc).
//
// Follows RM0433 (Rev 7) section 15 "Direct memory access controller (DMA)": "DMA streams",
// "Source, destination and transfer modes" (one data item per peripheral request,
// memory-to-peripheral with MINC), "Circular mode" (NDTR and the addresses reload when NDTR
// reaches 0, the stream stays enabled), "Double-buffer mode" (CT switches M0AR/M1AR at each
// end), "DMA transfer suspension" (clearing EN stops the stream: NDTR keeps the items left,
// and TCIF is set to say the transfer ended; the same text in RM0399 16.3.16 and RM0090
// 10.3.14, and "DMA transfer completion" lists "the stream is disabled by software"), "DMA interrupts" (HTIF when half the items of
// the block are transferred, TCIF at the end, each with its enable in SxCR), and the register
// map (LISR/HISR, LIFCR/HIFCR, SxCR, SxNDTR, SxPAR, SxM0AR, SxM1AR, SxFCR).
//
// Why: Renode 1.15.3's STM32DMA copies a whole block when a request comes, has no circular
// or double-buffer mode and no half-transfer interrupt, and reads NDTR back as written; the
// step path needs one item per request, the stream going round its buffer for a whole run,
// both interrupts, and NDTR as it stands (the refill and the e-stop read where a stream is).
//
// Requests come in as GPIO inputs 0-7 (one per stream, from DMAMUX1's channels), one item
// per rising edge (no FIFO: direct mode only; the FIFO threshold register reads back).
// Outputs 0-7: the streams' interrupt lines.
//
// Time (issue 34): each item takes `transferNanoseconds` of virtual time, one at a time per
// controller, and lands (is written to its destination, NDTR counts it, its flags rise) at
// the end of that time, so a timer sees its DMA burst when it lands, not at its update event.
// Which pending request goes next is RM0433 15.3 "DMA arbitration": the higher software
// priority (SxCR.PL) first, between equal ones the lower stream number; arbitration is made
// again after every item, so a stream's three-word timer burst can be overtaken between its
// words by a lower-numbered stream, and with every stream at "very high" the last stream
// waits for all the others. 0 (the default) serves each request at once, as before issue 34.
// The chip publishes no figure for one item: the step path's resc gives the profile's
// estimate (ten 200 MHz bus cycles for a memory read and an AHB-to-APB write, scaled to the
// emulated timer clock); a test can slow it (`TransferNanoseconds`) to see what a late burst
// does. A stream disabled while its item is under way: the item lands at the disabling write
// (RM0433 "DMA transfer suspension": the transfer under way completes first).
//
using System;
using System.Collections.Generic;
using Antmicro.Renode.Core;
using Antmicro.Renode.Logging;
using Antmicro.Renode.Peripherals.Bus;
using Antmicro.Renode.Peripherals.Timers;
using Antmicro.Renode.Time;

namespace Antmicro.Renode.Peripherals.DMA
{
    public class STM32H7_StepDMA : IDoubleWordPeripheral, IKnownSize, IGPIOReceiver, INumberedGPIOOutput
    {
        public STM32H7_StepDMA(IMachine machine, long transferNanoseconds = 0)
        {
            this.machine = machine;
            sysbus = machine.GetSystemBus(this);
            TransferNanoseconds = transferNanoseconds;
            // The landing of the item under way, counted in nanoseconds (1 GHz: one count per
            // Renode time tick), as the step timers schedule their events.
            landing = new LimitTimer(machine.ClockSource, 1000000000, this, "transfer", limit: ulong.MaxValue,
                direction: Direction.Ascending, enabled: false, workMode: WorkMode.OneShot, eventEnabled: true);
            landing.LimitReached += OnLanding;
            streams = new Stream[NumberOfStreams];
            var connections = new Dictionary<int, IGPIO>();
            for(var i = 0; i < NumberOfStreams; i++)
            {
                streams[i] = new Stream();
                connections[i] = streams[i].Irq;
            }
            Connections = connections;
            TransferCompleteOnDisable = true;
            Reset();
        }

        public IReadOnlyDictionary<int, IGPIO> Connections { get; }

        public long Size => 0x400;

        /// RM0433 "DMA transfer suspension": a stream disabled by software sets its TCIF.
        /// On by default, as the manual says; off only to show what a firmware that reads the
        /// flags after the stop would see without it.
        public bool TransferCompleteOnDisable { get; set; }

        /// Items moved by each stream since reset.
        public ulong Transfers(int stream) => streams[stream].Transfers;

        /// Requests that came while their stream was disabled (dropped).
        public ulong DroppedRequests { get; private set; }

        /// Virtual time one item takes, ns (0: served at once).
        public long TransferNanoseconds { get; set; }

        /// The longest wait of a stream's request for its item to land, ns (0 untimed).
        public long LongestWaitNanoseconds(int stream) => streams[stream].LongestWait;

        public void Reset()
        {
            foreach(var s in streams)
            {
                s.Reset();
            }
            pending = new int[NumberOfStreams];
            servicing = false;
            landing.Enabled = false;
            inFlight = -1;
        }

        public uint ReadDoubleWord(long offset)
        {
            if(offset == LISR || offset == HISR)
            {
                var first = offset == LISR ? 0 : 4;
                uint value = 0;
                for(var i = 0; i < 4; i++)
                {
                    value |= streams[first + i].Flags << FlagShift[i];
                }
                return value;
            }
            if(offset == LIFCR || offset == HIFCR)
            {
                return 0;
            }
            if(!StreamRegister(offset, out var s, out var register))
            {
                this.Log(LogLevel.Warning, "read from 0x{0:X}: not a register", offset);
                return 0;
            }
            var stream = streams[s];
            switch(register)
            {
                case CR: return stream.Cr | (stream.Enabled ? CR_EN : 0);
                // Running or stopped, the items left (after a stop: where it stopped, RM0433 "DMA
                // transfer suspension").
                case NDTR: return stream.Left;
                case PAR: return stream.Par;
                case M0AR: return stream.M0ar;
                case M1AR: return stream.M1ar;
                default: return stream.Fcr | 0x20; // FCR.FS: FIFO empty
            }
        }

        public void WriteDoubleWord(long offset, uint value)
        {
            if(offset == LIFCR || offset == HIFCR)
            {
                var first = offset == LIFCR ? 0 : 4;
                for(var i = 0; i < 4; i++)
                {
                    var clear = (value >> FlagShift[i]) & FlagMask;
                    streams[first + i].Flags &= ~clear;
                    UpdateIrq(first + i);
                }
                return;
            }
            if(offset == LISR || offset == HISR)
            {
                return;
            }
            if(!StreamRegister(offset, out var s, out var register))
            {
                this.Log(LogLevel.Warning, "write 0x{0:X} to 0x{1:X}: not a register", value, offset);
                return;
            }
            var stream = streams[s];
            switch(register)
            {
                case CR:
                    if(TransferNanoseconds > 0)
                    {
                        // The CPU's instructions up to this write into virtual time, so that an
                        // item that lands before it has landed.
                        SyncCpuTime();
                    }
                    WriteControl(s, value);
                    break;
                case NDTR:
                    // Writable only while the stream is disabled (RM0433 SxNDTR).
                    if(!stream.Enabled)
                    {
                        stream.Left = value & 0xFFFF;
                    }
                    break;
                case PAR:
                    if(!stream.Enabled)
                    {
                        stream.Par = value;
                    }
                    break;
                case M0AR:
                    if(!stream.Enabled || (stream.Cr & CR_CT) != 0)
                    {
                        stream.M0ar = value;
                    }
                    break;
                case M1AR:
                    if(!stream.Enabled || (stream.Cr & CR_CT) == 0)
                    {
                        stream.M1ar = value;
                    }
                    break;
                default:
                    stream.Fcr = value & 0xBF;
                    break;
            }
        }

        // A peripheral request (through DMAMUX1): one item per rising edge.
        public void OnGPIO(int number, bool value)
        {
            if(number < 0 || number >= NumberOfStreams || !value)
            {
                return;
            }
            pending[number]++;
            if(TransferNanoseconds > 0)
            {
                streams[number].Requested.Enqueue(ClockNow());
                if(inFlight < 0 && !servicing)
                {
                    StartNext();
                }
                return;
            }
            if(servicing)
            {
                // A transfer of ours made the peripheral ask for its next item (a timer's
                // DMA burst): served when the current one is done.
                return;
            }
            servicing = true;
            try
            {
                for(var busy = true; busy;)
                {
                    busy = false;
                    for(var i = 0; i < NumberOfStreams; i++)
                    {
                        if(pending[i] > 0)
                        {
                            pending[i]--;
                            busy = true;
                            if(streams[i].Enabled)
                            {
                                TransferOne(i);
                            }
                            else
                            {
                                DroppedRequests++;
                            }
                        }
                    }
                }
            }
            finally
            {
                servicing = false;
            }
        }

        // ---- time (TransferNanoseconds > 0) ----

        private long ClockNow() => (long)machine.ClockSource.CurrentValue.Ticks;

        private void SyncCpuTime()
        {
            if(machine.SystemBus.TryGetCurrentCPU(out var cpu) && cpu.OnPossessedThread)
            {
                cpu.SyncTime();
            }
        }

        // Arbitration (RM0433 "DMA arbitration"): of the streams with a request, the highest
        // SxCR.PL, then the lowest number. Requests of disabled streams are dropped. The
        // winner's item lands TransferNanoseconds from now.
        private void StartNext()
        {
            var best = -1;
            uint bestLevel = 0;
            for(var i = 0; i < NumberOfStreams; i++)
            {
                if(pending[i] == 0)
                {
                    continue;
                }
                if(!streams[i].Enabled)
                {
                    DroppedRequests += (ulong)pending[i];
                    pending[i] = 0;
                    streams[i].Requested.Clear();
                    continue;
                }
                var level = (streams[i].Cr >> 16) & 3;
                if(best < 0 || level > bestLevel)
                {
                    best = i;
                    bestLevel = level;
                }
            }
            if(best < 0)
            {
                return;
            }
            pending[best]--;
            inFlight = best;
            landing.Enabled = false;
            landing.Value = 0;
            landing.Limit = (ulong)TransferNanoseconds;
            landing.Enabled = true;
        }

        private void OnLanding()
        {
            landing.Enabled = false;
            Land();
            StartNext();
        }

        // The item under way lands now: written, counted, flagged. A request it makes (the
        // timer's next burst word) waits for the arbitration that follows.
        private void Land()
        {
            var s = inFlight;
            inFlight = -1;
            if(s < 0)
            {
                return;
            }
            var stream = streams[s];
            if(stream.Requested.Count > 0)
            {
                var wait = ClockNow() - stream.Requested.Dequeue();
                if(wait > stream.LongestWait)
                {
                    stream.LongestWait = wait;
                }
            }
            servicing = true;
            try
            {
                if(stream.Enabled)
                {
                    TransferOne(s);
                }
            }
            finally
            {
                servicing = false;
            }
        }

        private void WriteControl(int s, uint value)
        {
            var stream = streams[s];
            var enable = (value & CR_EN) != 0;
            if(stream.Enabled)
            {
                // While enabled only EN (and CT in double-buffer mode, by hardware) changes.
                if(!enable)
                {
                    if(inFlight == s)
                    {
                        // The item under way completes first, then the stream stops.
                        landing.Enabled = false;
                        Land();
                    }
                    stream.Enabled = false;
                    if(TransferCompleteOnDisable)
                    {
                        stream.Flags |= TCIF;
                    }
                    UpdateIrq(s);
                    if(TransferNanoseconds > 0 && inFlight < 0 && !servicing)
                    {
                        StartNext();
                    }
                }
                return;
            }
            stream.Cr = value & ~CR_EN;
            if(enable)
            {
                if(stream.Left == 0)
                {
                    // Nothing to transfer: the stream does not start.
                    return;
                }
                if((stream.Cr & (CR_PFCTRL | CR_PBURST | CR_MBURST)) != 0)
                {
                    this.Log(LogLevel.Warning, "stream {0}: flow control and bursts are not modelled (CR 0x{1:X})", s, value);
                }
                stream.Enabled = true;
                stream.Block = stream.Left;
                stream.Index = 0;
                if(((stream.Cr >> 6) & 3) == 2)
                {
                    // Memory to memory: no request, the whole block at once.
                    while(stream.Enabled && stream.Left > 0)
                    {
                        TransferOne(s);
                    }
                }
            }
        }

        private void TransferOne(int s)
        {
            var stream = streams[s];
            var cr = stream.Cr;
            var direction = (cr >> 6) & 3;
            var psize = 1 << (int)((cr >> 11) & 3);
            var msize = 1 << (int)((cr >> 13) & 3);
            var memoryBase = (cr & CR_CT) != 0 ? stream.M1ar : stream.M0ar;
            var memory = (ulong)memoryBase + ((cr & CR_MINC) != 0 ? (ulong)(stream.Index * msize) : 0);
            var peripheral = (ulong)stream.Par + ((cr & CR_PINC) != 0 ? (ulong)(stream.Index * psize) : 0);
            ulong from, to;
            int size;
            if(direction == 0)
            {
                from = peripheral;
                to = memory;
                size = psize;
            }
            else
            {
                from = direction == 1 ? memory : (ulong)stream.Par + (ulong)(stream.Index * psize);
                to = direction == 1 ? peripheral : memory;
                size = direction == 1 ? msize : psize;
            }
            // Book-keeping first: the write below can make the peripheral ask again.
            stream.Index++;
            stream.Left--;
            stream.Transfers++;
            var half = stream.Block / 2;
            if(stream.Left == stream.Block - half && half > 0)
            {
                stream.Flags |= HTIF;
            }
            if(stream.Left == 0)
            {
                stream.Flags |= TCIF;
                if((cr & (CR_CIRC | CR_DBM)) != 0)
                {
                    stream.Left = stream.Block;
                    stream.Index = 0;
                    if((cr & CR_DBM) != 0)
                    {
                        stream.Cr ^= CR_CT;
                    }
                }
                else
                {
                    stream.Enabled = false;
                }
            }
            switch(size)
            {
                case 1:
                    sysbus.WriteByte(to, sysbus.ReadByte(from));
                    break;
                case 2:
                    sysbus.WriteWord(to, sysbus.ReadWord(from));
                    break;
                default:
                    sysbus.WriteDoubleWord(to, sysbus.ReadDoubleWord(from));
                    break;
            }
            UpdateIrq(s);
        }

        private void UpdateIrq(int s)
        {
            var stream = streams[s];
            var cr = stream.Cr;
            var f = stream.Flags;
            var on = ((f & TCIF) != 0 && (cr & CR_TCIE) != 0)
                || ((f & HTIF) != 0 && (cr & CR_HTIE) != 0)
                || ((f & TEIF) != 0 && (cr & CR_TEIE) != 0)
                || ((f & DMEIF) != 0 && (cr & CR_DMEIE) != 0)
                || ((f & FEIF) != 0 && (stream.Fcr & 0x80) != 0);
            stream.Irq.Set(on);
        }

        private static bool StreamRegister(long offset, out int stream, out long register)
        {
            stream = (int)((offset - 0x10) / 0x18);
            register = (offset - 0x10) % 0x18;
            return offset >= 0x10 && stream < NumberOfStreams && (register % 4) == 0;
        }

        private const int NumberOfStreams = 8;
        private const long LISR = 0x00, HISR = 0x04, LIFCR = 0x08, HIFCR = 0x0C;
        private const long CR = 0x00, NDTR = 0x04, PAR = 0x08, M0AR = 0x0C, M1AR = 0x10;
        private const uint CR_EN = 1u << 0, CR_DMEIE = 1u << 1, CR_TEIE = 1u << 2, CR_HTIE = 1u << 3, CR_TCIE = 1u << 4,
            CR_PFCTRL = 1u << 5, CR_CIRC = 1u << 8, CR_PINC = 1u << 9, CR_MINC = 1u << 10, CR_DBM = 1u << 18,
            CR_CT = 1u << 19, CR_PBURST = 3u << 21, CR_MBURST = 3u << 23;
        private const uint FEIF = 1u << 0, DMEIF = 1u << 2, TEIF = 1u << 3, HTIF = 1u << 4, TCIF = 1u << 5, FlagMask = 0x3D;
        // Where each of the four streams' flags sit in LISR/HISR (and the clear registers).
        private static readonly int[] FlagShift = { 0, 6, 16, 22 };

        private readonly IMachine machine;
        private readonly IBusController sysbus;
        private readonly Stream[] streams;
        private readonly LimitTimer landing;
        private int[] pending;
        private bool servicing;
        // The stream whose item is under way (timed), or -1.
        private int inFlight;

        private class Stream
        {
            public Stream()
            {
                Irq = new GPIO();
            }

            public void Reset()
            {
                Cr = Fcr = Par = M0ar = M1ar = Left = Block = Flags = 0;
                Index = 0;
                Enabled = false;
                Irq.Set(false);
                Requested.Clear();
                LongestWait = 0;
            }

            public GPIO Irq { get; }
            public uint Cr, Fcr, Par, M0ar, M1ar, Left, Block, Flags;
            public int Index;
            public bool Enabled;
            public ulong Transfers;
            // When each request still waiting for its item came (ns), and the longest wait.
            public readonly Queue<long> Requested = new Queue<long>();
            public long LongestWait;
        }
    }
}
