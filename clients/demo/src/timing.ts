/**
 * The two clocks of the page: a fixed-rate timer for the solve loop (targets go out at
 * 60 Hz whatever the screen draws) and a meter of events per second (solves answered,
 * frames drawn), for the readout.
 */

/** Calls `tick(now)` at deadlines `start + k / hz` on a timer (`setTimeout`, not
 * `requestAnimationFrame`: a slow draw does not slow the ticks). A tick that fires late
 * does not push the later ones back; a wait of more than a whole period (the main thread
 * was busy) drops the deadlines it missed rather than firing them back to back, which
 * would only send the same targets again. */
export class FixedRate {
  /** Deadlines dropped because the timer fired more than a period late. */
  missed = 0;
  private readonly periodMs: number;
  private next = 0;
  private timer: ReturnType<typeof setTimeout> | undefined;

  constructor(
    hz: number,
    private readonly tick: (now: number) => void,
  ) {
    this.periodMs = 1000 / hz;
  }

  start(): void {
    this.stop();
    this.next = performance.now();
    this.schedule();
  }

  stop(): void {
    clearTimeout(this.timer);
    this.timer = undefined;
  }

  private schedule(): void {
    this.timer = setTimeout(() => this.fire(), Math.max(0, this.next - performance.now()));
  }

  private fire(): void {
    const now = performance.now();
    this.next += this.periodMs;
    const behind = Math.floor((now - this.next) / this.periodMs);
    if (behind > 0) {
      this.missed += behind;
      this.next += behind * this.periodMs;
    }
    this.schedule(); // first: a throw in `tick` must not end the loop
    this.tick(now);
  }
}

/** How many events (`mark`) fell in the last `spanMs`, per second. */
export class RateMeter {
  private readonly times: number[] = [];

  constructor(private readonly spanMs = 1000) {}

  mark(now: number): void {
    this.times.push(now);
    this.forget(now);
  }

  perSecond(now: number): number {
    this.forget(now);
    return (this.times.length * 1000) / this.spanMs;
  }

  private forget(now: number): void {
    while (this.times.length > 0 && this.times[0]! <= now - this.spanMs) this.times.shift();
  }
}
