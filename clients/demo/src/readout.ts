/** The per-frame readout: what the newest answer said, round trips over the last frames, and
 * how many frames per second are solved and drawn. */

import type { CompactFrameResult } from "../../typescript/src/index.js";

const WINDOW = 600; // frames kept for the percentiles (10 s at 60 frames/s)

function cell(id: string): HTMLElement {
  return document.getElementById(id)!;
}

/** Set a cell's text only when it changes (an unchanged cell costs no layout). */
function write(id: string, text: string): void {
  const element = cell(id);
  if (element.textContent !== text) element.textContent = text;
}

/** The q-th quantile (0..1) of `values`, nearest rank. */
export function quantile(values: readonly number[], q: number): number {
  if (values.length === 0) return Number.NaN;
  const sorted = [...values].sort((a, b) => a - b);
  return sorted[Math.min(sorted.length - 1, Math.ceil(q * sorted.length) - 1)] ?? Number.NaN;
}

/** Largest change of any joint between two poses [rad or m]. */
export function largestStep(previous: readonly number[] | null, q: readonly number[]): number {
  if (previous === null || previous.length !== q.length) return 0;
  return q.reduce((largest, value, i) => Math.max(largest, Math.abs(value - previous[i]!)), 0);
}

/** The newest answer and what the readout shows with it. */
interface Shown {
  result: CompactFrameResult;
  roundTripMs: number;
  stepRad: number;
}

/** Counts every answer as it arrives (`frame`) and writes the table when a frame is
 * drawn (`render`): the DOM changes at most once per drawn frame, whatever the solve
 * rate, and what it shows is the newest answer. */
export class Readout {
  frames = 0;
  solved = 0;
  roundTripsMs: number[] = [];
  private newest: Shown | null = null;

  status(text: string): void {
    cell("r-status").textContent = text;
  }

  frame(result: CompactFrameResult, roundTripMs: number, stepRad: number): void {
    this.frames += 1;
    if (result.success) this.solved += 1;
    this.roundTripsMs.push(roundTripMs);
    if (this.roundTripsMs.length > WINDOW) this.roundTripsMs.shift();
    this.newest = { result, roundTripMs, stepRad };
  }

  /** Write the newest answer (if one came since the last call) and the two rates. */
  render(solvesPerS: number, drawnPerS: number): void {
    write("r-rates", `${solvesPerS.toFixed(0)} solves/s, ${drawnPerS.toFixed(0)} drawn frames/s`);
    if (this.newest === null) return;
    const { result, roundTripMs, stepRad } = this.newest;
    this.newest = null;
    cell("r-frames").textContent = `${this.solved} / ${this.frames}`;
    cell("r-termination").textContent = `${result.termination} (${result.status})`;
    cell("r-solve").textContent = `${result.solve_us.toFixed(0)} us`;
    cell("r-server").textContent = `${result.server_us.toFixed(0)} us`;
    cell("r-round-trip").textContent = `${roundTripMs.toFixed(2)} ms`;
    const p50 = quantile(this.roundTripsMs, 0.5);
    const p99 = quantile(this.roundTripsMs, 0.99);
    cell("r-percentiles").textContent = `${p50.toFixed(2)} / ${p99.toFixed(2)} ms`;
    cell("r-step").textContent = `${stepRad.toFixed(4)} rad`;
  }

  reset(): void {
    this.frames = 0;
    this.solved = 0;
    this.roundTripsMs = [];
    this.newest = null;
  }
}
