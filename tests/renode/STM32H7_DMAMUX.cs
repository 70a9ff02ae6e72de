//
// DMAMUX1 of the STM32H743, request routing only, for Renode 1.15.3 (loaded at run time by
// tests/renode/step-path.resc).
//
// Follows RM0433 (Rev 7) section 17 "DMA request multiplexer (DMAMUX)": "DMAMUX request line
// multiplexer" (channel x forwards the request input selected by DMAMUX_CxCR.DMAREQ_ID to
// its DMA stream: channels 0-7 to DMA1 streams 0-7, channels 8-15 to DMA2 streams 0-7) and
// the table "DMAMUX1: assignment of multiplexer inputs to resources" (which request number
// each peripheral drives: TIM1_UP 15, TIM2_UP 22, TIM3_UP 27, TIM4_UP 32, TIM8_UP 51,
// TIM5_UP 59, TIM16_UP 110, TIM17_UP 112; the .resc wires the timers accordingly).
//
// Why: the stock stm32h743.repl maps DMAMUX1 as a bare tag region, so no request reaches a
// stream. Not modelled: synchronisation (SE, SYNC_ID, NBREQ), event generation (EGE) and the
// request generators; the registers read back.
//
// GPIO inputs 1-127: request lines by number. Outputs 0-15: one per channel.
//
using System;
using System.Collections.Generic;
using Antmicro.Renode.Core;
using Antmicro.Renode.Logging;
using Antmicro.Renode.Peripherals.Bus;

namespace Antmicro.Renode.Peripherals.Miscellaneous
{
    public class STM32H7_DMAMUX : IDoubleWordPeripheral, IKnownSize, IGPIOReceiver, INumberedGPIOOutput
    {
        public STM32H7_DMAMUX()
        {
            var connections = new Dictionary<int, IGPIO>();
            for(var i = 0; i < Channels; i++)
            {
                outputs[i] = new GPIO();
                connections[i] = outputs[i];
            }
            Connections = connections;
            Reset();
        }

        public IReadOnlyDictionary<int, IGPIO> Connections { get; }

        public long Size => 0x400;

        public void Reset()
        {
            Array.Clear(ccr, 0, ccr.Length);
            Array.Clear(requests, 0, requests.Length);
            other.Clear();
            foreach(var o in outputs)
            {
                o.Set(false);
            }
        }

        public uint ReadDoubleWord(long offset)
        {
            if(offset >= 0 && offset < Channels * 4)
            {
                return ccr[offset / 4];
            }
            return other.TryGetValue(offset, out var v) ? v : 0;
        }

        public void WriteDoubleWord(long offset, uint value)
        {
            if(offset >= 0 && offset < Channels * 4)
            {
                var channel = (int)(offset / 4);
                ccr[channel] = value;
                if((value & ~0x7Fu) != 0)
                {
                    this.Log(LogLevel.Warning, "channel {0}: synchronisation and events are not modelled (CCR 0x{1:X})", channel, value);
                }
                // The channel now follows its new request line.
                outputs[channel].Set(requests[value & 0x7F]);
                return;
            }
            other[offset] = value;
        }

        public void OnGPIO(int number, bool value)
        {
            if(number <= 0 || number >= requests.Length)
            {
                return;
            }
            requests[number] = value;
            for(var i = 0; i < Channels; i++)
            {
                if((ccr[i] & 0x7F) == number)
                {
                    outputs[i].Set(value);
                }
            }
        }

        private const int Channels = 16;
        private readonly uint[] ccr = new uint[Channels];
        private readonly bool[] requests = new bool[128];
        private readonly GPIO[] outputs = new GPIO[Channels];
        private readonly Dictionary<long, uint> other = new Dictionary<long, uint>();
    }
}
