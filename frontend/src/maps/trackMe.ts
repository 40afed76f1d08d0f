/**
 * The phone's motion sensors for "Track me": permission (iOS asks through
 * DeviceMotionEvent/DeviceOrientationEvent.requestPermission, which must run inside the
 * tap), then accelerometer samples and absolute headings from whichever source delivers
 * first — the Generic Sensor API (Accelerometer + AbsoluteOrientationSensor) where the
 * browser offers it, else devicemotion + deviceorientation(absolute) events.
 *
 * Times are the sensor's own clock: each devicemotion sample is `interval` ms after the
 * previous one, unless the events' time stamps are more than half a second further apart
 * (samples lost, e.g. the page was in the background); headings take the time of the
 * newest motion sample. (Event time stamps alone jitter with the page's own work.)
 */
import { headingFromCompass, headingFromEuler, headingFromQuaternion } from "../tracker/live";

export interface SensorFeed {
  motion(t_ms: number, ax: number, ay: number, az: number): void;
  heading(t_ms: number, rad: number): void;
  /** What is delivering ("generic sensors", "device motion events"), or why nothing is. */
  status(text: string): void;
}

type PermissionAsker = { requestPermission?: () => Promise<"granted" | "denied"> };

/** Ask for motion and orientation access where the browser wants it asked (iOS). Null when granted. */
export async function askMotionPermission(): Promise<string | null> {
  for (const ctor of [globalThis.DeviceMotionEvent, globalThis.DeviceOrientationEvent] as unknown as (PermissionAsker | undefined)[]) {
    if (ctor && typeof ctor.requestPermission === "function") {
      try {
        if ((await ctor.requestPermission()) !== "granted") return "motion sensor access was denied; allow it in the browser's settings";
      } catch (err) {
        return `motion sensor access could not be asked for: ${(err as Error).message}`;
      }
    }
  }
  return null;
}

interface GenericSensor extends EventTarget {
  start(): void;
  stop(): void;
  timestamp?: number;
  x?: number;
  y?: number;
  z?: number;
  quaternion?: number[];
}

/** Start listening; returns the function that stops every listener and sensor. */
export function listenSensors(feed: SensorFeed): () => void {
  let source: "generic" | "events" | null = null;
  let clock = -Infinity; // ms of the newest motion sample
  let lastStamp = 0; // event time stamp of the newest motion sample
  let sawAbsolute = false;
  const stops: (() => void)[] = [];

  const claim = (s: "generic" | "events") => {
    if (source === null) {
      source = s;
      feed.status(s === "generic" ? "sensors: Generic Sensor API" : "sensors: device motion events");
    }
    return source === s;
  };

  const onMotion = (e: DeviceMotionEvent) => {
    const g = e.accelerationIncludingGravity;
    if (!g || g.x === null || g.y === null || g.z === null || !claim("events")) return;
    const gap = e.timeStamp - lastStamp;
    const dt = e.interval || gap;
    clock = clock === -Infinity ? 0 : clock + (gap > dt + 500 ? gap : dt);
    lastStamp = e.timeStamp;
    feed.motion(clock, g.x, g.y, g.z);
  };
  const onOrientation = (e: DeviceOrientationEvent) => {
    if (source === "generic" || clock === -Infinity) return;
    const compass = (e as DeviceOrientationEvent & { webkitCompassHeading?: number }).webkitCompassHeading;
    if (typeof compass === "number" && Number.isFinite(compass)) return feed.heading(clock, headingFromCompass(compass));
    if (e.alpha === null || e.beta === null) return;
    if (e.type === "deviceorientationabsolute" || e.absolute) {
      sawAbsolute = true;
      feed.heading(clock, headingFromEuler(e.alpha, e.beta));
    } else if (!sawAbsolute) feed.status("this browser gives no compass heading (deviceorientation is not absolute): the track cannot be placed on the floor");
  };
  window.addEventListener("devicemotion", onMotion);
  window.addEventListener("deviceorientationabsolute", onOrientation as EventListener);
  window.addEventListener("deviceorientation", onOrientation);
  stops.push(() => {
    window.removeEventListener("devicemotion", onMotion);
    window.removeEventListener("deviceorientationabsolute", onOrientation as EventListener);
    window.removeEventListener("deviceorientation", onOrientation);
  });

  const w = window as unknown as Record<string, (new (o: { frequency: number }) => GenericSensor) | undefined>;
  const Acc = w.Accelerometer;
  const Ori = w.AbsoluteOrientationSensor;
  if (Acc && Ori) {
    try {
      const acc = new Acc({ frequency: 50 });
      const ori = new Ori({ frequency: 50 });
      let t0: number | null = null;
      acc.addEventListener("reading", () => {
        if (acc.timestamp === undefined || !claim("generic")) return;
        t0 ??= acc.timestamp;
        clock = acc.timestamp - t0;
        feed.motion(clock, acc.x ?? 0, acc.y ?? 0, acc.z ?? 0);
      });
      ori.addEventListener("reading", () => {
        const q = ori.quaternion;
        if (source !== "generic" || !q) return;
        feed.heading(clock, headingFromQuaternion(q[0], q[1], q[2], q[3]));
      });
      // Without sensor hardware (desktops) they report an error; the events may still come.
      acc.start();
      ori.start();
      stops.push(() => (acc.stop(), ori.stop()));
    } catch {
      /* not allowed here (permissions policy): the events remain */
    }
  }
  return () => stops.forEach((s) => s());
}
