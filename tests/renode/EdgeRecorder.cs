//
// Records GPIO edges with their virtual time, for the Renode tests of the step path
// (tests/renode/step-path.resc, tests/tests/renode_steps.rs). Not a chip peripheral: a
// probe on lines, as a logic analyser on the NUCLEO's pins would be.
//
// It sits on the system bus at an address the chip leaves reserved (step-path.resc) only so
// that the monitor can reach it by name (`@ none` peripherals have none); reading its one
// register gives the number of edges recorded.
//
// Each input is one line (the .resc connects the STEP pins, the DIR pins and the joint
// timers' "counting" outputs; `Watch` hooks a GPIO port's pin). Every change is written as
// `<virtual time in ns> <input> <0|1>` to `Path`. The time is the machine clock source's
// (Renode's virtual time, 1 ns resolution): a timer's edge is recorded at the event's own
// time; a pin the CPU writes (DIR) at the last point the CPU reported its progress, which
// this recorder brings up to date first (SyncTime) when it is called on the CPU's thread
// from a register write.
//
// It is also a network probe (issue 30): connected to the board's switch in promiscuous mode
// (`connector Connect sysbus.stepRecorder switch; switch EnablePromiscuousMode
// sysbus.stepRecorder`), it gets every frame at the virtual time the switch hands it to the
// board's MAC too, and records each UDP datagram to `StopPort` that is a STOPPED frame
// (tag 0x03 as the payload's second byte; CRC not checked) as input `StopInput`, level 1: the
// moment a STOPPED landed, to compare with the last STEP edge after it.
//
using System;
using System.IO;
using Antmicro.Renode.Core;
using Antmicro.Renode.Core.Structure;
using Antmicro.Renode.Network;
using Antmicro.Renode.Peripherals.Network;
using Antmicro.Renode.Exceptions;
using Antmicro.Renode.Logging;
using Antmicro.Renode.Peripherals.Bus;

namespace Antmicro.Renode.Peripherals.Miscellaneous
{
    public class EdgeRecorder : IDoubleWordPeripheral, IKnownSize, IGPIOReceiver, IMACInterface
    {
        public EdgeRecorder(IMachine machine)
        {
            this.machine = machine;
        }

        /// Where the edges go (a new file; set before the run).
        public string Path
        {
            get => path;
            set
            {
                lock(sync)
                {
                    writer?.Dispose();
                    path = value;
                    writer = new StreamWriter(value, false);
                }
            }
        }

        /// Edges recorded so far.
        public ulong Edges { get; private set; }

        /// Connects pin `pin` of the GPIO port named `port` (e.g. "sysbus.gpioPortD") to
        /// input `input`, beside whatever the pin already drives.
        public void Watch(string port, int pin, int input)
        {
            if(!machine.TryGetByName<INumberedGPIOOutput>(port, out var peripheral))
            {
                throw new RecoverableException($"no GPIO output peripheral named {port}");
            }
            peripheral.Connections[pin].Connect(this, input);
        }

        /// Writes out what is buffered (the test reads the file while the machine runs).
        public void Flush()
        {
            lock(sync)
            {
                writer?.Flush();
            }
        }

        public void OnGPIO(int number, bool value)
        {
            Record(number, value);
        }

        private void Record(int number, bool value)
        {
            if(machine.SystemBus.TryGetCurrentCPU(out var cpu) && cpu.OnPossessedThread)
            {
                cpu.SyncTime();
            }
            var ns = machine.ClockSource.CurrentValue.Ticks;
            lock(sync)
            {
                Edges++;
                writer?.Write($"{ns} {number} {(value ? 1 : 0)}\n");
            }
        }

        public void Reset()
        {
        }

        /// The input number a STOPPED datagram's landing is recorded as.
        public int StopInput { get; set; } = 32;

        /// The controller's UDP port.
        public int StopPort { get; set; } = 8510;

        /// Never sends; any address (promiscuous mode receives all).
        public MACAddress MAC { get; set; }

        public event Action<EthernetFrame> FrameReady
        {
            add { }
            remove { }
        }

        public void ReceiveFrame(EthernetFrame frame)
        {
            if(IsStopped(frame.Bytes))
            {
                Record(StopInput, true);
            }
        }

        /// An IPv4 UDP datagram to StopPort whose payload's second byte is STOPPED's tag.
        private bool IsStopped(byte[] b)
        {
            if(b.Length < 14 + 20 + 8 + 3 || b[12] != 0x08 || b[13] != 0x00 || b[23] != 17)
            {
                return false;
            }
            var udp = 14 + (b[14] & 0xF) * 4;
            if(b.Length < udp + 8 + 3)
            {
                return false;
            }
            var port = (b[udp + 2] << 8) | b[udp + 3];
            var payload = ((b[udp + 4] << 8) | b[udp + 5]) - 8;
            return port == StopPort && payload >= 3 && payload <= 8 && b[udp + 8 + 1] == 0x03;
        }

        public long Size => 0x10;

        public uint ReadDoubleWord(long offset) => (uint)Edges;

        public void WriteDoubleWord(long offset, uint value)
        {
        }

        private readonly IMachine machine;
        private readonly object sync = new object();
        private string path;
        private StreamWriter writer;
    }
}
