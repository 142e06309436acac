/**
 * The service's built-in example chains (panda_arm, humanoid_arm, tail, two_arm_torso),
 * drawn from their joints (`/demo/examples.json`) and posed by the answers' `q`.
 *
 * These chains have no bones, so the server sends joint values only: the page computes
 * each link's frame itself, as the solver does (solver/model/chain.py):
 * `link = parent * origin * Tr(pivot) * motion(q) * Tr(-pivot)`, a rotational joint's
 * motion being one rotation per axis in the order given. The chains are Z up; their root
 * is turned a quarter about X so that they stand in the Y-up scene, and targets are sent
 * in the chain's frame.
 */

import * as THREE from "three";

import type { DofInfo, Target } from "../../typescript/src/index.js";

interface FrameJson {
  translation: [number, number, number];
  rotation: [number, number, number, number]; // w, x, y, z
}

interface JointJson {
  name: string;
  parent: string;
  child: string;
  kind: "fixed" | "rotational" | "revolute" | "continuous" | "prismatic";
  origin: FrameJson;
  pivot: [number, number, number];
  axis: [number, number, number];
  axes: string;
}

export interface ExampleJson {
  joints: JointJson[];
  effectors: { name: string; link: string; mode: "position" | "pose" | "aim"; tip: FrameJson }[];
}

const AXES: Record<string, THREE.Vector3> = {
  x: new THREE.Vector3(1, 0, 0),
  y: new THREE.Vector3(0, 1, 0),
  z: new THREE.Vector3(0, 0, 1),
};

function matrixOf(frame: FrameJson): THREE.Matrix4 {
  const [w, x, y, z] = frame.rotation;
  return new THREE.Matrix4().compose(
    new THREE.Vector3(...frame.translation),
    new THREE.Quaternion(x, y, z, w),
    new THREE.Vector3(1, 1, 1),
  );
}

export class ExampleChain {
  readonly root = new THREE.Group();
  private readonly links = new Map<string, THREE.Object3D>();
  private readonly tips = new Map<string, THREE.Object3D>();
  private readonly orientations = new Map<string, THREE.Quaternion>();

  constructor(
    readonly name: string,
    private readonly spec: ExampleJson,
  ) {
    this.root.rotation.x = -Math.PI / 2; // Z up -> the scene's Y up
    const stick = new THREE.MeshStandardMaterial({ color: 0xc8ccd4, roughness: 0.6 });
    const ball = new THREE.Mesh(new THREE.SphereGeometry(0.02, 12, 8), new THREE.MeshStandardMaterial({ color: 0x4a5568 }));
    const link = (name: string): THREE.Object3D => {
      let object = this.links.get(name);
      if (object === undefined) {
        object = new THREE.Object3D();
        object.matrixAutoUpdate = false;
        object.add(ball.clone());
        this.links.set(name, object);
      }
      return object;
    };
    const children = new Set(spec.joints.map((j) => j.child));
    for (const joint of spec.joints) {
      const parent = link(joint.parent);
      if (!children.has(joint.parent) && parent.parent === null) this.root.add(parent);
      const child = link(joint.child);
      parent.add(child);
      // A stick from the parent's origin to the joint's.
      const offset = new THREE.Vector3(...joint.origin.translation).add(new THREE.Vector3(...joint.pivot));
      if (offset.length() > 1e-6) parent.add(this.stick(offset, stick));
    }
    for (const effector of spec.effectors) {
      const tip = new THREE.Object3D();
      tip.matrixAutoUpdate = false;
      tip.matrix.copy(matrixOf(effector.tip));
      link(effector.link).add(tip);
      const offset = new THREE.Vector3(...effector.tip.translation);
      if (offset.length() > 1e-6) link(effector.link).add(this.stick(offset, stick));
      this.tips.set(effector.name, tip);
    }
  }

  static async load(url: string): Promise<Map<string, ExampleChain>> {
    const response = await fetch(url);
    if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
    const all = (await response.json()) as Record<string, ExampleJson>;
    return new Map(Object.entries(all).map(([name, spec]) => [name, new ExampleChain(name, spec)]));
  }

  get effectors(): string[] {
    return this.spec.effectors.map((e) => e.name);
  }

  /** Pose the links for `q` (values in the order of `dof`, as the session lists them). */
  setQ(q: readonly number[], dof: readonly DofInfo[]): void {
    const value = new Map(dof.map((d, i) => [d.name, q[i] ?? 0]));
    for (const joint of this.spec.joints) {
      const m = matrixOf(joint.origin).multiply(new THREE.Matrix4().makeTranslation(...joint.pivot));
      if (joint.kind === "rotational") {
        for (const a of joint.axes) m.multiply(new THREE.Matrix4().makeRotationAxis(AXES[a]!, value.get(`${joint.name}.${a}`) ?? 0));
      } else if (joint.kind === "prismatic") {
        const d = new THREE.Vector3(...joint.axis).multiplyScalar(value.get(joint.name) ?? 0);
        m.multiply(new THREE.Matrix4().makeTranslation(d.x, d.y, d.z));
      } else if (joint.kind !== "fixed") {
        m.multiply(new THREE.Matrix4().makeRotationAxis(new THREE.Vector3(...joint.axis).normalize(), value.get(joint.name) ?? 0));
      }
      m.multiply(new THREE.Matrix4().makeTranslation(-joint.pivot[0], -joint.pivot[1], -joint.pivot[2]));
      this.links.get(joint.child)!.matrix.copy(m);
    }
    this.root.updateMatrixWorld(true);
  }

  /** An effector's tip in the scene. */
  worldPosition(name: string): THREE.Vector3 {
    this.root.updateMatrixWorld(true);
    return this.tips.get(name)!.getWorldPosition(new THREE.Vector3());
  }

  /** Keep each pose effector's current orientation as its target's (the page drags
   * positions only). */
  holdOrientations(): void {
    const rootInverse = this.root.getWorldQuaternion(new THREE.Quaternion()).invert();
    for (const e of this.spec.effectors) {
      const q = this.tips.get(e.name)!.getWorldQuaternion(new THREE.Quaternion());
      this.orientations.set(e.name, rootInverse.clone().multiply(q));
    }
  }

  /** The target for an effector whose handle is at `world` (scene coordinates). */
  target(name: string, world: THREE.Vector3): Target {
    const p = this.root.worldToLocal(world.clone());
    const target: Target = { effector: name, position: { x: p.x, y: p.y, z: p.z } };
    const mode = this.spec.effectors.find((e) => e.name === name)?.mode;
    const q = this.orientations.get(name);
    if (mode === "pose" && q !== undefined) target.orientation = { w: q.w, x: q.x, y: q.y, z: q.z };
    return target;
  }

  private stick(offset: THREE.Vector3, material: THREE.Material): THREE.Mesh {
    const mesh = new THREE.Mesh(new THREE.CylinderGeometry(0.012, 0.012, offset.length(), 8), material);
    mesh.position.copy(offset).multiplyScalar(0.5);
    mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), offset.clone().normalize());
    return mesh;
  }
}
