/**
 * The demo character: a glTF skeleton (service/demo_assets/character.gltf) as a three.js
 * node tree drawn as sticks, and the chain settings the session is created with.
 *
 * The server answers with each moving bone's local rotation in three.js's conventions
 * (preset `threejs`, as glTF): `apply` writes them into the nodes' quaternions, exactly
 * what a game does with its own skeleton; the effectors' world positions are then read
 * off the scene graph, not from the server.
 */

import * as THREE from "three";

import type { GltfChain, Quaternion } from "../../typescript/src/index.js";

/** The effectors the page drags: hands and feet, each on the bone of the same name. */
export const EFFECTORS = ["hand_L", "hand_R", "foot_L", "foot_R"] as const;
export type EffectorName = (typeof EFFECTORS)[number];

/** Bones that move: a spine, two arms and two legs (19 DOF). Elbows bend forward, knees
 * backward (about each bone's x axis); shoulders and hips are ball joints (the server's
 * default ranges). The rest pose (arms and legs straight down) is where solving starts. */
const MOVING = ["spine", "upper_arm_L", "forearm_L", "upper_arm_R", "forearm_R", "thigh_L", "shin_L", "thigh_R", "shin_R"];
const BONE_SETTINGS = {
  spine: { axes: "xyz", lower: [-0.3, -0.4, -0.3], upper: [0.5, 0.4, 0.3] },
  forearm_L: { axes: "x", lower: [-2.6], upper: [0] },
  forearm_R: { axes: "x", lower: [-2.6], upper: [0] },
  shin_L: { axes: "x", lower: [0], upper: [2.6] },
  shin_R: { axes: "x", lower: [0], upper: [2.6] },
};

interface GltfNode {
  name?: string;
  translation?: [number, number, number];
  rotation?: [number, number, number, number];
  children?: number[];
}

interface GltfDocument {
  nodes: GltfNode[];
  skins: { joints: number[] }[];
}

export class Character {
  readonly root = new THREE.Group();
  private readonly bones = new Map<string, THREE.Object3D>();

  private constructor(readonly gltf: GltfDocument) {
    const made = gltf.nodes.map((node, index) => {
      const bone = new THREE.Object3D();
      bone.name = node.name ?? `node_${index}`;
      if (node.translation) bone.position.fromArray(node.translation);
      if (node.rotation) bone.quaternion.fromArray(node.rotation); // glTF: x, y, z, w
      this.bones.set(bone.name, bone);
      return bone;
    });
    const isChild = new Set(gltf.nodes.flatMap((node) => node.children ?? []));
    gltf.nodes.forEach((node, index) => {
      for (const child of node.children ?? []) made[index]!.add(made[child]!);
      if (!isChild.has(index)) this.root.add(made[index]!);
    });
    this.drawSticks(made, gltf);
  }

  static async load(url: string): Promise<Character> {
    const response = await fetch(url);
    if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
    return new Character((await response.json()) as GltfDocument);
  }

  /** The session's chain: this file's skin, the moving bones, limits and effectors. */
  chain(): GltfChain {
    return {
      format: "gltf",
      gltf: this.gltf as unknown as Record<string, unknown>,
      moving: MOVING,
      bones: BONE_SETTINGS,
      effectors: EFFECTORS.map((bone) => ({ bone, mode: "position" as const })),
    };
  }

  /** Set bone local rotations (the server's `bones.local`). */
  apply(local: Record<string, Quaternion>): void {
    for (const [name, q] of Object.entries(local)) this.bones.get(name)?.quaternion.set(q.x, q.y, q.z, q.w);
    this.root.updateMatrixWorld(true);
  }

  /** Every moving bone's current local rotation (to restore a pose). */
  localRotations(): Record<string, Quaternion> {
    const out: Record<string, Quaternion> = {};
    for (const name of MOVING) {
      const q = this.bones.get(name)!.quaternion;
      out[name] = { w: q.w, x: q.x, y: q.y, z: q.z };
    }
    return out;
  }

  /** World position of a bone's origin (the effectors sit on them). */
  worldPosition(name: string): THREE.Vector3 {
    this.root.updateMatrixWorld(true);
    return this.bones.get(name)!.getWorldPosition(new THREE.Vector3());
  }

  /** A stick from each bone to each child, and a ball on each joint, as children of the
   * bones (so they follow the rotations with no per-frame work). */
  private drawSticks(made: THREE.Object3D[], gltf: GltfDocument): void {
    const stick = new THREE.MeshStandardMaterial({ color: 0xc8ccd4, roughness: 0.6 });
    const joint = new THREE.MeshStandardMaterial({ color: 0x4a5568, roughness: 0.5 });
    const ball = new THREE.SphereGeometry(0.025, 12, 8);
    const up = new THREE.Vector3(0, 1, 0);
    gltf.nodes.forEach((node, index) => {
      const bone = made[index]!;
      bone.add(new THREE.Mesh(ball, joint));
      for (const child of node.children ?? []) {
        const offset = made[child]!.position.clone();
        const length = offset.length();
        const mesh = new THREE.Mesh(new THREE.CylinderGeometry(0.018, 0.022, length, 10), stick);
        mesh.position.copy(offset).multiplyScalar(0.5);
        mesh.quaternion.setFromUnitVectors(up, offset.normalize());
        bone.add(mesh);
      }
    });
  }
}
