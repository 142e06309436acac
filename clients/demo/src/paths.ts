/**
 * Both joint paths of a recorded drag: as it was tracked live (solid) and as the server
 * planned it as a whole clip (dashed), one colour per joint, over the clip's frames.
 */

const COLOURS = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324"];

export function drawPaths(canvas: HTMLCanvasElement, tracked: number[][], planned: number[][]): void {
  const context = canvas.getContext("2d");
  if (context === null || tracked.length === 0) return;
  const all = [...tracked, ...planned].flat();
  const low = Math.min(...all);
  const high = Math.max(...all);
  const span = high - low || 1;
  const x = (i: number): number => (i / Math.max(1, tracked.length - 1)) * (canvas.width - 8) + 4;
  const y = (v: number): number => canvas.height - 4 - ((v - low) / span) * (canvas.height - 8);
  context.clearRect(0, 0, canvas.width, canvas.height);
  // The joints that moved most: a few readable lines rather than every DOF.
  const n = tracked[0]!.length;
  const moved = Array.from({ length: n }, (_, j) => j)
    .map((j) => ({ j, range: Math.max(...tracked.map((q) => q[j]!)) - Math.min(...tracked.map((q) => q[j]!)) }))
    .sort((a, b) => b.range - a.range)
    .slice(0, COLOURS.length);
  moved.forEach(({ j }, k) => {
    context.strokeStyle = COLOURS[k]!;
    for (const [path, dash] of [
      [tracked, []],
      [planned, [4, 3]],
    ] as const) {
      context.setLineDash(dash);
      context.beginPath();
      path.forEach((q, i) => (i === 0 ? context.moveTo(x(i), y(q[j]!)) : context.lineTo(x(i), y(q[j]!))));
      context.stroke();
    }
  });
  context.setLineDash([]);
}
