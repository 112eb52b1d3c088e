// The tracker side of `imuflow bench live`: SlimeVR's own tracker emulator
// (@slimevr/tracker-emulation, pinned in package.json) plays N trackers with one sensor each
// against a SlimeVR server (here imuflow's slimevr source), sending one rotation (data type
// NORMAL) and one linear acceleration per tracker per tick, as the firmware does after each fusion
// update, from a file of per-tracker samples, paced on the monotonic clock.
//
//   npm ci --prefix tools/live-bench
//   node tools/live-bench/emulate.mjs --data samples.csv --rate 100 --log sends.csv
//
// --data: CSV with the header `tick,tracker,qx,qy,qz,qw,ax,ay,az`: per tick and tracker the
//   rotation (x, y, z, w, the tracker's frame to its inertial frame) and the linear acceleration
//   (m/s², gravity removed, tracker frame). Ticks 0.. in order, every tracker in every tick.
// --server HOST, --port PORT: where the server listens (default 127.0.0.1:6969); the trackers'
//   handshakes go there (serverDiscoveryIP/port) instead of the broadcast address.
// --rate HZ: ticks per second (default 100).
// --burst-every S, --burst-stall MS: every S seconds after the first tick, send nothing for MS
//   milliseconds, then send the ticks that fell due meanwhile back to back, each with its own data
//   (a Wi-Fi stall: the motion goes on, its packets arrive late and together). 0: no stalls.
// --log FILE: one row per tick and tracker: `tick,tracker,due_ns,send_ns`: when the tick was due
//   and when the emulator was asked to send its rotation, ns since the Unix epoch on the host clock
//   (the monotonic clock, anchored once to the wall clock at a millisecond edge of Date.now()).
// --connect-timeout S: give up when not every tracker is connected after S seconds (default 30).
// --macs MAC,MAC,...: the trackers' MACs, in the data's tracker order (default 02:53:4c:00:00:01,
//   02:53:4c:00:00:02, ...: the MACs of configs/trackers/slimevr-sim.toml).
//
// Prints `connected N trackers after S s` once all are connected and, at the end, one line
// `summary {json}`. Exits 0 when every tick was sent; 1 on an error; 3 when the trackers did not
// connect in time. SIGTERM / SIGINT stop the sending; the log is written either way.

import { readFileSync, writeFileSync } from 'node:fs';
import { setImmediate as immediate, setTimeout as sleep } from 'node:timers/promises';
import { MACAddress, Quaternion, Vector } from '@slimevr/common';
import {
    BoardType,
    FirmwareFeatureFlags,
    MCUType,
    RotationDataType,
    SensorStatus,
    SensorType
} from '@slimevr/firmware-protocol';
import { EmulatedTracker } from '@slimevr/tracker-emulation';

function parseArgs(argv) {
    const options = {
        server: '127.0.0.1',
        port: 6969,
        rate: 100,
        burstEvery: 0,
        burstStall: 0,
        connectTimeout: 30,
        macs: null,
        data: null,
        log: null
    };
    const names = {
        '--server': ['server', String],
        '--port': ['port', Number],
        '--rate': ['rate', Number],
        '--burst-every': ['burstEvery', Number],
        '--burst-stall': ['burstStall', Number],
        '--connect-timeout': ['connectTimeout', Number],
        '--macs': ['macs', String],
        '--data': ['data', String],
        '--log': ['log', String]
    };
    for (let i = 0; i < argv.length; i += 2) {
        const spec = names[argv[i]];
        if (!spec || i + 1 >= argv.length) throw new Error(`unknown or incomplete argument '${argv[i]}'`);
        const value = spec[1](argv[i + 1]);
        if (spec[1] === Number && !Number.isFinite(value)) throw new Error(`${argv[i]}: not a number: '${argv[i + 1]}'`);
        options[spec[0]] = value;
    }
    if (!options.data || !options.log) throw new Error('--data and --log are required');
    if (!(options.rate > 0)) throw new Error('--rate must be positive');
    return options;
}

/** Ticks of samples: ticks[k][i] = { q: [x, y, z, w], a: [x, y, z] }. */
function readSamples(path) {
    const lines = readFileSync(path, 'utf8').split('\n').filter((l) => l.trim() !== '');
    const header = lines.shift().trim();
    if (header !== 'tick,tracker,qx,qy,qz,qw,ax,ay,az') throw new Error(`${path}: unexpected header '${header}'`);
    const ticks = [];
    for (const [n, line] of lines.entries()) {
        const v = line.split(',').map(Number);
        if (v.length !== 9 || !v.every(Number.isFinite)) throw new Error(`${path}: line ${n + 2} is not 9 numbers`);
        const [tick, tracker] = v;
        while (ticks.length <= tick) ticks.push([]);
        ticks[tick][tracker] = { q: v.slice(2, 6), a: v.slice(6, 9) };
    }
    const trackers = ticks.length ? ticks[0].length : 0;
    for (const [k, t] of ticks.entries()) {
        if (t.length !== trackers || t.some((s) => s === undefined)) throw new Error(`${path}: tick ${k} does not hold all ${trackers} trackers`);
    }
    if (trackers === 0) throw new Error(`${path}: no samples`);
    return { ticks, trackers };
}

const hrNow = () => process.hrtime.bigint();

/** The monotonic clock anchored to the wall clock: waits for Date.now() to tick over (a
 * millisecond edge) and pairs that edge with the monotonic time. */
function anchor() {
    const first = Date.now();
    let ms = first;
    let hr = hrNow();
    while (ms === first) {
        hr = hrNow();
        ms = Date.now();
    }
    return { epochNs: BigInt(ms) * 1000000n, hr };
}

const lock = new Int32Array(new SharedArrayBuffer(4));

/** Waits until the monotonic time `target` (bigint ns): a timer for anything longer than 50 ms
 * (the event loop keeps answering the server's heartbeats), a futex wait (Atomics.wait, precise
 * to tens of µs, where timers are late by milliseconds on a busy machine) up to 200 µs before,
 * a spin for the rest. Between ticks the event loop runs once (the caller yields after sending). */
async function waitUntil(target) {
    for (;;) {
        const left = Number(target - hrNow());
        if (left <= 0) return;
        if (left > 50e6) {
            await sleep((left - 20e6) / 1e6);
        } else if (left > 3e5) {
            Atomics.wait(lock, 0, 0, (left - 2e5) / 1e6);
        }
        // else: spin
    }
}

async function main() {
    const options = parseArgs(process.argv.slice(2));
    const { ticks, trackers: count } = readSamples(options.data);
    const macs = [];
    for (let i = 0; i < count; i++) {
        const text = options.macs ? options.macs.split(',')[i] : `02:53:4c:00:00:${(i + 1).toString(16).padStart(2, '0')}`;
        const bytes = (text ?? '').split(':').map((h) => (/^[0-9a-fA-F]{2}$/.test(h) ? parseInt(h, 16) : NaN));
        if (bytes.length !== 6 || bytes.some(Number.isNaN)) throw new Error(`--macs: tracker ${i}: not a MAC: '${text}'`);
        macs.push(bytes);
    }

    let stopped = false;
    for (const sig of ['SIGTERM', 'SIGINT']) process.on(sig, () => { stopped = true; });

    const trackers = [];
    const sensors = [];
    const errors = [];
    let disconnects = 0;
    let closing = false;
    const connected = new Set();
    let allConnected;
    const connectedPromise = new Promise((resolve) => { allConnected = resolve; });
    for (let i = 0; i < count; i++) {
        const tracker = new EmulatedTracker(
            new MACAddress(macs[i]),
            'imuflow-live-bench',
            new FirmwareFeatureFlags(new Map()),
            BoardType.SLIMEVR,
            MCUType.ESP32_C3,
            options.server,
            options.port
        );
        tracker.on('error', (e) => {
            console.error(`emulate: tracker ${i}: ${e.message ?? e}`);
            if (errors.length < 10) errors.push(`tracker ${i}: ${e.message ?? e}`);
        });
        tracker.on('connected-to-server', () => {
            connected.add(i);
            if (connected.size === count) allConnected();
        });
        tracker.on('disconnected-from-server', (why) => {
            if (closing) return; // deinit() at the end disconnects each tracker ('manual')
            disconnects += 1;
            connected.delete(i);
            console.error(`emulate: tracker ${i} disconnected: ${why?.message ?? why}`);
            if (errors.length < 10) errors.push(`tracker ${i} disconnected: ${why?.message ?? why}`);
        });
        sensors.push(await tracker.addSensor(SensorType.BNO085, SensorStatus.OK));
        trackers.push(tracker);
    }
    const connectStarted = hrNow();
    for (const t of trackers) await t.init();
    const timedOut = await Promise.race([
        connectedPromise.then(() => false),
        sleep(options.connectTimeout * 1000).then(() => true)
    ]);
    if (timedOut || stopped) {
        closing = true;
        console.error(`emulate: ${connected.size} of ${count} trackers connected to ${options.server}:${options.port} within ${options.connectTimeout} s${stopped ? ' (stopped)' : ''}; is the slimevr source listening there, with these MACs in its trackers file?`);
        for (const t of trackers) await t.deinit();
        process.exit(3);
    }
    console.log(`connected ${count} trackers after ${(Number(hrNow() - connectStarted) / 1e9).toFixed(2)} s`);
    // Let the sensor info the trackers sent on connecting be acknowledged before the data.
    await sleep(200);

    const periodNs = 1e9 / options.rate;
    const clock = anchor();
    const start = hrNow() + 20000000n; // 20 ms from now
    const everyNs = options.burstEvery * 1e9;
    const stallNs = options.burstStall * 1e6;
    /** When tick k goes out, relative to the start (ns): its due time, or the end of the stall it
     * falls into. */
    const release = (dueNs) => {
        if (!(everyNs > 0 && stallNs > 0)) return dueNs;
        const j = Math.floor(dueNs / everyNs);
        if (j >= 1 && dueNs < j * everyNs + stallNs) return j * everyNs + stallNs;
        return dueNs;
    };
    const log = ['tick,tracker,due_ns,send_ns'];
    const epoch = (hr) => clock.epochNs + (hr - clock.hr);
    const lateNs = [];
    let stalledTicks = 0;
    let sent = 0;
    let pending = [];
    for (let k = 0; k < ticks.length && !stopped; k++) {
        const dueRel = Math.round(k * periodNs);
        const releaseRel = release(dueRel);
        const due = start + BigInt(dueRel);
        const target = start + BigInt(releaseRel);
        if (releaseRel !== dueRel) stalledTicks += 1;
        await waitUntil(target);
        const now = hrNow();
        if (releaseRel === dueRel) lateNs.push(Number(now - target));
        for (let i = 0; i < count; i++) {
            const s = ticks[k][i];
            const t = hrNow();
            pending.push(sensors[i].sendRotation(RotationDataType.NORMAL, new Quaternion(...s.q), 0));
            pending.push(sensors[i].sendAcceleration(new Vector(...s.a)));
            log.push(`${k},${i},${epoch(due)},${epoch(t)}`);
        }
        sent += 1;
        // The datagrams leave once this turn of the event loop ends (dgram resolves the address on
        // the next tick): yield so they go now, also between the ticks of a burst.
        await immediate();
        if (pending.length >= 64 * count) {
            await Promise.all(pending);
            pending = [];
        }
    }
    await Promise.all(pending);
    const end = anchor();
    // How far the monotonic clock drifted from the wall clock over the run (NTP slewing).
    const driftNs = Number(end.epochNs - epoch(end.hr));
    writeFileSync(options.log, log.join('\n') + '\n');
    lateNs.sort((a, b) => a - b);
    const pct = (p) => (lateNs.length ? lateNs[Math.min(lateNs.length - 1, Math.round((lateNs.length - 1) * p))] / 1e3 : 0);
    const summary = {
        emulator: '@slimevr/tracker-emulation 0.2.6',
        trackers: count,
        ticks: ticks.length,
        ticks_sent: sent,
        samples_sent: sent * count,
        packets_sent: sent * count * 2,
        rate_hz: options.rate,
        stalled_ticks: stalledTicks,
        pacing_late_p50_us: pct(0.5),
        pacing_late_p99_us: pct(0.99),
        pacing_late_max_us: pct(1),
        clock_drift_us: driftNs / 1e3,
        disconnects,
        errors,
        stopped
    };
    console.log(`summary ${JSON.stringify(summary)}`);
    closing = true;
    for (const t of trackers) await t.deinit();
    process.exit(sent === ticks.length && disconnects === 0 ? 0 : 1);
}

main().catch((e) => {
    console.error(`emulate: ${e.stack ?? e}`);
    process.exit(1);
});
