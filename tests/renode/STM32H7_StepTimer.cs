//
// A model of the STM32H743's timers as the arm controller's step path uses them, for Renode
// 1.15.3 (loaded at run time by tests/renode/step-path.resc, `include @...cs`).
//
// Follows RM0433 (STM32H742/743/753/750 reference manual, Rev 7):
//   38 "Advanced-control timers (TIM1/TIM8)", 39 "General-purpose timers (TIM2/TIM3/TIM4/
//   TIM5)", 40 "General-purpose timers (TIM12/TIM13/TIM14)", 41 "General-purpose timers
//   (TIM15/TIM16/TIM17)"; in each: "Time-base unit" (PSC, ARR and CCRx preload, the update
//   event, UDIS/URS, EGR.UG), "Repetition counter" (TIM1/8/15/16/17), "PWM mode" (OCxM =
//   PWM mode 1: OCxREF active while CNT < CCRx), "Forced output mode", "Complementary
//   outputs and dead-time insertion" (table "Output control bits for complementary OCx and
//   OCxN channels with break feature"), "Using the break function", "DMA burst mode" and the
//   TIMx_DCR/TIMx_DMAR register descriptions.
//
// Why a model of our own: Renode's stock STM32_Timer raises no DMA request (DIER.UDE is a
// tag), has no DCR/DMAR burst, no complementary output, no main output enable and no
// repetition counter on the update event as the step path uses them; its compare channels
// run at the constructor's frequency, so changing a timer's clock leaves them behind.
//
// Time: the counter is not stepped tick by tick. Its state is "the counter was 0 at timer
// cycle P" while it runs, and every event (a compare match, an overflow) is computed from
// that with integer arithmetic and handed to Renode's clock source as a one-shot deadline
// in nanoseconds (Renode's time resolution). At 200 MHz a cycle is exactly 5 ns, so every
// edge this model makes lands on its exact tick in virtual time. Register accesses from the
// CPU first sync the CPU's executed instructions into virtual time (SyncTime), so CEN, a
// forced-inactive write or a CNT read happen at the instruction that made them.
//
// What is not modelled: input capture, slave modes and triggers, encoder mode, centre-aligned
// and down counting, dead time, the OCxCE clear, the RCC reset of the timer (the firmware
// rewrites every register it uses after its RCC reset) and DBGMCU freeze.
//
// DMA latency (issue 34): a DMAR write takes effect when the DMA model lands it (its time per
// item, STM32H7_StepDMA.cs), at the virtual time it lands. A burst still open at the next
// update event is late: that update loads the preload registers as they are, so the period
// before is played again, and its own DMA request is lost (the request is a level, still
// raised for the open burst, RM0433 "DMA burst mode"): every later period comes one period
// late, an extra pulse that neither the stream's NDTR nor the producer counts, which is the
// chip's behaviour as issue 34 describes it. `LateBursts` counts them.
//
// GPIO outputs (Connections): 0 = CH1 (OC1), 1 = CH1N (OC1N), 2 = update DMA request (to
// DMAMUX1), 3 = counting (CR1.CEN, for the edge recorder: the timer's tick 0), 4 = IRQ
// (update and compare flags with their DIER enables). GPIO input 0 = break input (BKIN /
// system break).
//
using System;
using System.Collections.Generic;
using Antmicro.Renode.Core;
using Antmicro.Renode.Logging;
using Antmicro.Renode.Peripherals.Bus;
using Antmicro.Renode.Time;

namespace Antmicro.Renode.Peripherals.Timers
{
    public class STM32H7_StepTimer : IDoubleWordPeripheral, IKnownSize, INumberedGPIOOutput, IGPIOReceiver
    {
        public STM32H7_StepTimer(IMachine machine, long frequency = 200000000, int counterBits = 16,
            bool advanced = false, bool repetitionCounter = false, int channels = 4)
        {
            this.machine = machine;
            this.frequency = frequency;
            this.advanced = advanced;
            this.hasRepetition = repetitionCounter;
            this.channels = Math.Max(1, Math.Min(4, channels));
            counterMax = counterBits >= 32 ? 0xFFFFFFFFUL : (1UL << counterBits) - 1;
            // Exact nanoseconds per cycle when the clock divides 1 GHz (200 MHz: 5 ns).
            nsPerCycle = (1000000000L % frequency == 0) ? 1000000000L / frequency : 0;
            ch1 = new GPIO();
            ch1n = new GPIO();
            dmaRequest = new GPIO();
            counting = new GPIO();
            irq = new GPIO();
            connections = new Dictionary<int, IGPIO>
            {
                { 0, ch1 }, { 1, ch1n }, { 2, dmaRequest }, { 3, counting }, { 4, irq },
            };
            // The deadline of the next event, counted in nanoseconds (1 GHz: one count per
            // Renode time tick).
            scheduler = new LimitTimer(machine.ClockSource, 1000000000, this, "events", limit: ulong.MaxValue,
                direction: Direction.Ascending, enabled: false, workMode: WorkMode.OneShot, eventEnabled: true);
            scheduler.LimitReached += OnDeadline;
            Reset();
        }

        public long Size => 0x400;

        public IReadOnlyDictionary<int, IGPIO> Connections => connections;

        /// Events (edges, update events) that were handled later than their own time (only
        /// when an access found them due before the deadline fired); 0 in a good run.
        public ulong LateEvents { get; private set; }

        /// Update events so far (each one a DMA request when DIER.UDE is set).
        public ulong UpdateEvents { get; private set; }

        /// DMA requests raised, and DMAR writes received.
        public ulong DmaRequests { get; private set; }
        public ulong DmarWrites { get; private set; }

        /// Update events that came while the DMA burst of the previous one was still open
        /// (landing late): each replayed the period before. 0 in a good run.
        public ulong LateBursts { get; private set; }

        public void Reset()
        {
            scheduler.Enabled = false;
            cr1 = cr2 = smcr = dier = sr = ccmr1 = ccmr2 = ccer = bdtr = dcr = 0;
            psc = pscActive = 0;
            arr = arrActive = counterMax;
            rcr = 0;
            repetitionLeft = 0;
            for(var i = 0; i < 4; i++)
            {
                ccr[i] = ccrActive[i] = 0;
                compareDone[i] = false;
            }
            other.Clear();
            running = false;
            wrapAtMax = false;
            stoppedCount = 0;
            periodStart = 0;
            anchorNs = 0;
            ref1 = false;
            burstIndex = 0;
            burstOpen = false;
            ch1.Set(false);
            ch1n.Set(false);
            dmaRequest.Set(false);
            counting.Set(false);
            irq.Set(false);
        }

        public uint ReadDoubleWord(long offset)
        {
            if(inCatchUp)
            {
                return Read(offset, currentCycle);
            }
            var now = Now();
            CatchUp(now);
            var value = Read(offset, CycleAt(now));
            if(offset == DMAR)
            {
                Reschedule(now);
            }
            return value;
        }

        public void WriteDoubleWord(long offset, uint value)
        {
            if(inCatchUp)
            {
                // A DMA burst answering this timer's own update event: the state is the
                // event's, and the caller reschedules.
                Write(offset, value, currentCycle);
                return;
            }
            // A DMAR write is the DMA model's, landing at the clock's time (from its own
            // event, where the CPU's time must not be synced again); all others are the CPU's.
            var now = offset == DMAR ? (long)machine.ClockSource.CurrentValue.Ticks : Now();
            CatchUp(now);
            accessNs = now;
            var cycle = CycleAt(now);
            currentCycle = cycle;
            Write(offset, value, cycle);
            // CEN may have moved the cycle grid's origin.
            cycle = CycleAt(now);
            currentCycle = cycle;
            UpdateOutputs(cycle);
            Reschedule(now);
        }

        // Input 0: the break input. RM0433 "Using the break function": with BDTR.BKE, the
        // break input at its active level (BDTR.BKP) clears MOE at once, asynchronously; the
        // outputs take their idle state.
        public void OnGPIO(int number, bool value)
        {
            if(number != 0 || !advanced)
            {
                return;
            }
            var active = value == ((bdtr & BDTR_BKP) != 0);
            if(active && (bdtr & BDTR_BKE) != 0)
            {
                bdtr &= ~BDTR_MOE;
                sr |= SR_BIF;
                UpdateOutputs(currentCycle);
                UpdateIrq();
            }
        }

        // ---- time ----

        private long Now()
        {
            // The CPU may have executed instructions it has not reported yet: report them,
            // so that this access happens at its own instruction's time.
            if(machine.SystemBus.TryGetCurrentCPU(out var cpu) && cpu.OnPossessedThread)
            {
                cpu.SyncTime();
            }
            return (long)machine.ClockSource.CurrentValue.Ticks;
        }

        private long CycleAt(long ns)
        {
            var since = ns - anchorNs;
            if(nsPerCycle > 0)
            {
                return FloorDiv(since, nsPerCycle);
            }
            return (long)Math.Floor((decimal)since * frequency / 1000000000m);
        }

        private long NsOf(long cycle)
        {
            if(nsPerCycle > 0)
            {
                return anchorNs + cycle * nsPerCycle;
            }
            return anchorNs + (long)Math.Ceiling((decimal)cycle * 1000000000m / frequency);
        }

        private static long FloorDiv(long a, long b)
        {
            var q = a / b;
            if((a % b != 0) && ((a < 0) != (b < 0)))
            {
                q--;
            }
            return q;
        }

        private long TickLength => (long)pscActive + 1;

        // The counter's value at `cycle` (CNT).
        private ulong CountAt(long cycle)
        {
            if(!running)
            {
                return stoppedCount;
            }
            return (ulong)FloorDiv(cycle - periodStart, TickLength);
        }

        // Where the counter overflows in this period: after ARR, or (ARR written below the
        // count without preload, or CNT above ARR) after the counter's whole range.
        private ulong PeriodTicks => (wrapAtMax ? counterMax : arrActive) + 1;

        // The next event (cycle) after the current state: the earliest compare match not yet
        // made in this period, or the overflow.
        private long NextEvent(out int channel)
        {
            var overflow = periodStart + (long)PeriodTicks * TickLength;
            var next = overflow;
            channel = -1;
            for(var i = 0; i < channels; i++)
            {
                if(compareDone[i] || ccrActive[i] == 0 || ccrActive[i] > arrActive)
                {
                    continue;
                }
                var at = periodStart + (long)ccrActive[i] * TickLength;
                if(at < next)
                {
                    next = at;
                    channel = i;
                }
            }
            return next;
        }

        // Handles every event due at or before `now`, in time order.
        private void CatchUp(long now)
        {
            if(!running || inCatchUp)
            {
                return;
            }
            inCatchUp = true;
            try
            {
                var nowCycle = CycleAt(now);
                // Bounded: a stalled emulation catching up on seconds at a short period makes
                // many events, never an endless loop.
                for(var guard = 0; guard < 100000000 && running; guard++)
                {
                    var next = NextEvent(out var channel);
                    if(next > nowCycle)
                    {
                        break;
                    }
                    if(NsOf(next) < now)
                    {
                        LateEvents++;
                    }
                    currentCycle = next;
                    if(channel >= 0)
                    {
                        Compare(channel, next);
                    }
                    else
                    {
                        Overflow(next);
                    }
                }
            }
            finally
            {
                inCatchUp = false;
            }
        }

        private void Reschedule(long now)
        {
            scheduler.Enabled = false;
            if(!running)
            {
                return;
            }
            var next = NextEvent(out var _);
            var delta = NsOf(next) - now;
            if(delta < 1)
            {
                delta = 1;
            }
            scheduler.Value = 0;
            scheduler.Limit = (ulong)delta;
            scheduler.Enabled = true;
        }

        private void OnDeadline()
        {
            var now = (long)machine.ClockSource.CurrentValue.Ticks;
            CatchUp(now);
            Reschedule(now);
        }

        // ---- events ----

        private void Compare(int channel, long cycle)
        {
            compareDone[channel] = true;
            sr |= 1u << (channel + 1);
            if(channel == 0)
            {
                // PWM mode 1: inactive from CNT = CCR1 on; mode 2 the reverse.
                var mode = OcMode(0);
                if(mode == OC_PWM1)
                {
                    ref1 = false;
                }
                else if(mode == OC_PWM2)
                {
                    ref1 = true;
                }
                else if(mode == OC_TOGGLE)
                {
                    ref1 = !ref1;
                }
                else if(mode == OC_ACTIVE_ON_MATCH)
                {
                    ref1 = true;
                }
                else if(mode == OC_INACTIVE_ON_MATCH)
                {
                    ref1 = false;
                }
                UpdateOutputs(cycle);
            }
            UpdateIrq();
        }

        // Counter overflow at `cycle`: a new period starts; the update event (RM0433
        // "Update event", "Repetition counter") unless the repetition counter is not yet 0
        // or UDIS is set.
        private void Overflow(long cycle)
        {
            periodStart = cycle;
            wrapAtMax = false;
            for(var i = 0; i < 4; i++)
            {
                compareDone[i] = false;
            }
            MatchAtZero();
            if((cr1 & CR1_UDIS) != 0)
            {
                StartOfPeriodOutput(cycle);
                return;
            }
            if(hasRepetition && repetitionLeft > 0)
            {
                repetitionLeft--;
                StartOfPeriodOutput(cycle);
                return;
            }
            UpdateEvent(cycle, true);
            if((cr1 & CR1_OPM) != 0)
            {
                // One-pulse mode: the counter stops at the update event.
                running = false;
                stoppedCount = 0;
                counting.Set(false);
            }
        }

        // The update event: preload registers into the active ones, UIF, and the DMA request
        // (DIER.UDE). `fromOverflow` false: made by EGR.UG (URS = 1: no flag, no request).
        private void UpdateEvent(long cycle, bool fromOverflow)
        {
            UpdateEvents++;
            arrActive = arr;
            pscActive = psc;
            repetitionLeft = rcr;
            for(var i = 0; i < 4; i++)
            {
                ccrActive[i] = ccr[i];
                compareDone[i] = false;
            }
            MatchAtZero();
            StartOfPeriodOutput(cycle);
            var requests = fromOverflow || (cr1 & CR1_URS) == 0;
            if(requests)
            {
                sr |= SR_UIF;
                UpdateIrq();
                if((dier & DIER_UDE) != 0)
                {
                    RequestDma();
                }
            }
        }

        // A compare value of 0 matches as the counter starts a period (CNT = 0 = CCRx): the
        // step clock's alarm (TIM13) can have low bits 0.
        private void MatchAtZero()
        {
            for(var i = 0; i < channels; i++)
            {
                if(ccrActive[i] == 0)
                {
                    compareDone[i] = true;
                    sr |= 2u << i;
                }
            }
            UpdateIrq();
        }

        // At CNT = 0: PWM mode 1 is active when CCR1 > 0 (CNT < CCR1).
        private void StartOfPeriodOutput(long cycle)
        {
            var mode = OcMode(0);
            if(mode == OC_PWM1)
            {
                ref1 = ccrActive[0] > 0;
            }
            else if(mode == OC_PWM2)
            {
                ref1 = ccrActive[0] == 0;
            }
            UpdateOutputs(cycle);
        }

        // A DMA request: the DMA answers at once (through DMAMUX1, synchronously) with the
        // first write of the burst to DMAR; each DMAR write asks for the next until DBL + 1
        // transfers are done (RM0433 "DMA burst mode").
        private void RequestDma()
        {
            if(burstOpen)
            {
                // The last update's burst has not landed whole: this update replayed (part of)
                // the period before, and its request merges with the one still raised.
                LateBursts++;
                return;
            }
            DmaRequests++;
            burstIndex = 0;
            burstOpen = true;
            dmaRequest.Set(false);
            dmaRequest.Set(true);
        }

        private void DmarWrite(uint value, long cycle)
        {
            DmarWrites++;
            var dba = (int)(dcr & 0x1F);
            var dbl = (int)((dcr >> 8) & 0x1F);
            var target = (long)(dba + burstIndex) * 4;
            burstIndex++;
            Write(target, value, cycle);
            // The request falls after each transfer and rises again for the next one.
            dmaRequest.Set(false);
            if(burstIndex <= dbl)
            {
                dmaRequest.Set(true);
            }
            else
            {
                burstIndex = 0;
                burstOpen = false;
            }
        }

        // ---- outputs ----

        private uint OcMode(int channel)
        {
            var ccmr = channel < 2 ? ccmr1 : ccmr2;
            var shift = (channel % 2) * 8;
            var low = (ccmr >> (4 + shift)) & 7;
            var high = (ccmr >> (16 + shift)) & 1;
            return low | (high << 3);
        }

        // OC1 and OC1N from OC1REF and the enables: RM0433 "Complementary outputs and dead-time
        // insertion" (table of OCx/OCxN control bits) for the timers with a break feature;
        // TIM2-5 have OC1 alone (CC1E, CC1P).
        private void UpdateOutputs(long cycle)
        {
            var mode = OcMode(0);
            if(mode == OC_FORCE_INACTIVE)
            {
                ref1 = false;
            }
            else if(mode == OC_FORCE_ACTIVE)
            {
                ref1 = true;
            }
            else if(mode == OC_PWM1 || mode == OC_PWM2)
            {
                // Compared at all times, also with the counter stopped.
                var count = CountAt(cycle);
                var below = count < ccrActive[0];
                ref1 = mode == OC_PWM1 ? below : !below;
            }
            var cc1e = (ccer & CCER_CC1E) != 0;
            var cc1p = (ccer & CCER_CC1P) != 0;
            var cc1ne = (ccer & CCER_CC1NE) != 0;
            var cc1np = (ccer & CCER_CC1NP) != 0;
            bool oc1, oc1n;
            if(!advanced)
            {
                oc1 = cc1e && (ref1 ^ cc1p);
                oc1n = false;
            }
            else if((bdtr & BDTR_MOE) == 0)
            {
                // Idle state: with OSSI the outputs take their idle levels (CR2.OIS1/OIS1N),
                // otherwise they are disabled (low here: the pins are pulled down).
                var ossi = (bdtr & BDTR_OSSI) != 0;
                oc1 = ossi && cc1e && (cr2 & CR2_OIS1) != 0;
                oc1n = ossi && cc1ne && (cr2 & CR2_OIS1N) != 0;
            }
            else
            {
                // MOE = 1, no dead time: CC1E alone = OC1REF; CC1NE alone = OC1REF on OC1N;
                // both = complementary.
                oc1 = cc1e && (ref1 ^ cc1p);
                oc1n = cc1ne && ((cc1e ? !ref1 : ref1) ^ cc1np);
            }
            ch1.Set(oc1);
            ch1n.Set(oc1n);
        }

        private void UpdateIrq()
        {
            var pending = (sr & dier & 0x5F) != 0 || ((sr & SR_BIF) != 0 && (dier & DIER_BIE) != 0);
            irq.Set(pending);
        }

        // ---- registers ----

        private uint Read(long offset, long cycle)
        {
            switch(offset)
            {
                case CR1: return cr1 | (running ? CR1_CEN : 0);
                case CR2: return cr2;
                case SMCR: return smcr;
                case DIER: return dier;
                case SR: return sr;
                case EGR: return 0;
                case CCMR1: return ccmr1;
                case CCMR2: return ccmr2;
                case CCER: return ccer;
                case CNT: return (uint)CountAt(cycle);
                case PSC: return psc;
                case ARR: return (uint)arr;
                case RCR: return rcr;
                case CCR1: case CCR2: case CCR3: case CCR4:
                    return (uint)ccr[(offset - CCR1) / 4];
                case BDTR: return bdtr;
                case DCR: return dcr;
                case DMAR:
                {
                    var dba = (int)(dcr & 0x1F);
                    var dbl = (int)((dcr >> 8) & 0x1F);
                    var value = Read((long)(dba + burstIndex) * 4, cycle);
                    burstIndex = burstIndex + 1 > dbl ? 0 : burstIndex + 1;
                    return value;
                }
                default:
                    return other.TryGetValue(offset, out var v) ? v : 0;
            }
        }

        private void Write(long offset, uint value, long cycle)
        {
            switch(offset)
            {
                case CR1:
                {
                    var wasRunning = running;
                    var count = CountAt(cycle);
                    cr1 = value & ~CR1_CEN;
                    var run = (value & CR1_CEN) != 0;
                    if(run && !wasRunning)
                    {
                        // Counting starts here: the timer's cycle grid is anchored at this
                        // instant (the prescaler counter starts with CEN).
                        anchorNs = accessNs;
                        currentCycle = 0;
                        periodStart = -(long)count * TickLength;
                        running = true;
                        for(var i = 0; i < 4; i++)
                        {
                            compareDone[i] = ccrActive[i] <= count && ccrActive[i] != 0;
                        }
                        counting.Set(true);
                    }
                    else if(!run && wasRunning)
                    {
                        stoppedCount = count;
                        running = false;
                        counting.Set(false);
                    }
                    if((value & (CR1_DIR | CR1_CMS)) != 0)
                    {
                        this.Log(LogLevel.Warning, "down and centre-aligned counting are not modelled (CR1 = 0x{0:X})", value);
                    }
                    break;
                }
                case CR2: cr2 = value; break;
                case SMCR:
                    smcr = value;
                    if((value & 7) != 0)
                    {
                        this.Log(LogLevel.Warning, "slave modes are not modelled (SMCR = 0x{0:X})", value);
                    }
                    break;
                case DIER:
                    dier = value;
                    if((value & DIER_UDE) == 0)
                    {
                        // No request any more: a burst cut here is not waited for.
                        burstOpen = false;
                    }
                    UpdateIrq();
                    break;
                case SR:
                    // rc_w0: writing 0 clears a flag, 1 leaves it.
                    sr &= value;
                    UpdateIrq();
                    break;
                case EGR:
                    if((value & EGR_UG) != 0)
                    {
                        // Re-initialises the counter (and the prescaler counter) and makes an
                        // update event.
                        if(running)
                        {
                            periodStart = cycle;
                        }
                        else
                        {
                            stoppedCount = 0;
                        }
                        wrapAtMax = false;
                        UpdateEvent(cycle, false);
                    }
                    for(var i = 0; i < 4; i++)
                    {
                        if((value & (2u << i)) != 0)
                        {
                            sr |= 2u << i;
                        }
                    }
                    if((value & EGR_BG) != 0 && advanced)
                    {
                        bdtr &= ~BDTR_MOE;
                        sr |= SR_BIF;
                    }
                    UpdateIrq();
                    break;
                case CCMR1: ccmr1 = value; break;
                case CCMR2: ccmr2 = value; break;
                case CCER: ccer = value; break;
                case CNT:
                {
                    var count = (ulong)value & counterMax;
                    if(running)
                    {
                        periodStart = cycle - (long)count * TickLength;
                    }
                    else
                    {
                        stoppedCount = count;
                    }
                    wrapAtMax = count > arrActive;
                    for(var i = 0; i < 4; i++)
                    {
                        compareDone[i] = ccrActive[i] <= count && ccrActive[i] != 0;
                    }
                    break;
                }
                case PSC: psc = value & 0xFFFF; break;
                case ARR:
                    arr = (ulong)value & counterMax;
                    if((cr1 & CR1_ARPE) == 0)
                    {
                        arrActive = arr;
                        wrapAtMax = CountAt(cycle) > arrActive;
                    }
                    break;
                case RCR:
                    rcr = hasRepetition ? value & 0xFFFF : 0;
                    break;
                case CCR1: case CCR2: case CCR3: case CCR4:
                {
                    var i = (int)((offset - CCR1) / 4);
                    ccr[i] = (ulong)value & counterMax;
                    var preload = (i < 2 ? ccmr1 >> (i * 8) : ccmr2 >> ((i - 2) * 8)) & CCMR_OCPE;
                    if(preload == 0)
                    {
                        ccrActive[i] = ccr[i];
                        // A match happens when the counter reaches the new value, if it has not
                        // passed it yet in this period.
                        var count = CountAt(cycle);
                        compareDone[i] = ccrActive[i] <= count && ccrActive[i] != 0;
                    }
                    break;
                }
                case BDTR:
                    bdtr = advanced ? value : 0;
                    break;
                case DCR:
                    dcr = value;
                    burstIndex = 0;
                    burstOpen = false;
                    break;
                case DMAR:
                    DmarWrite(value, cycle);
                    break;
                default:
                    other[offset] = value;
                    break;
            }
        }

        // Register offsets (RM0433 timer register maps).
        private const long CR1 = 0x00, CR2 = 0x04, SMCR = 0x08, DIER = 0x0C, SR = 0x10, EGR = 0x14,
            CCMR1 = 0x18, CCMR2 = 0x1C, CCER = 0x20, CNT = 0x24, PSC = 0x28, ARR = 0x2C, RCR = 0x30,
            CCR1 = 0x34, CCR2 = 0x38, CCR3 = 0x3C, CCR4 = 0x40, BDTR = 0x44, DCR = 0x48, DMAR = 0x4C;

        private const uint CR1_CEN = 1u << 0, CR1_UDIS = 1u << 1, CR1_URS = 1u << 2, CR1_OPM = 1u << 3,
            CR1_DIR = 1u << 4, CR1_CMS = 3u << 5, CR1_ARPE = 1u << 7;
        private const uint CR2_OIS1 = 1u << 8, CR2_OIS1N = 1u << 9;
        private const uint DIER_UDE = 1u << 8, DIER_BIE = 1u << 7;
        private const uint SR_UIF = 1u << 0, SR_BIF = 1u << 7;
        private const uint EGR_UG = 1u << 0, EGR_BG = 1u << 7;
        private const uint CCMR_OCPE = 1u << 3;
        private const uint CCER_CC1E = 1u << 0, CCER_CC1P = 1u << 1, CCER_CC1NE = 1u << 2, CCER_CC1NP = 1u << 3;
        private const uint BDTR_OSSI = 1u << 10, BDTR_BKE = 1u << 12, BDTR_BKP = 1u << 13, BDTR_MOE = 1u << 15;

        // OCxM values (OCxM[3] in bit 3).
        private const uint OC_FROZEN = 0, OC_ACTIVE_ON_MATCH = 1, OC_INACTIVE_ON_MATCH = 2, OC_TOGGLE = 3,
            OC_FORCE_INACTIVE = 4, OC_FORCE_ACTIVE = 5, OC_PWM1 = 6, OC_PWM2 = 7;

        private readonly IMachine machine;
        private readonly long frequency;
        private readonly long nsPerCycle;
        private readonly bool advanced;
        private readonly bool hasRepetition;
        private readonly int channels;
        private readonly ulong counterMax;
        private readonly LimitTimer scheduler;
        private readonly GPIO ch1, ch1n, dmaRequest, counting, irq;
        private readonly Dictionary<int, IGPIO> connections;
        private readonly Dictionary<long, uint> other = new Dictionary<long, uint>();

        private uint cr1, cr2, smcr, dier, sr, ccmr1, ccmr2, ccer, bdtr, dcr, psc, pscActive, rcr, repetitionLeft;
        private ulong arr, arrActive;
        private readonly ulong[] ccr = new ulong[4];
        private readonly ulong[] ccrActive = new ulong[4];
        private readonly bool[] compareDone = new bool[4];
        private bool running, ref1, inCatchUp, wrapAtMax;
        private ulong stoppedCount;
        private long periodStart, anchorNs, currentCycle, accessNs;
        private int burstIndex;
        // A DMA burst requested and not yet written whole.
        private bool burstOpen;
    }
}
