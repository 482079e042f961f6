// The viewer page: Spark (three.js) draws an INRIA 3DGS PLY or an SPZ.
//
// Query parameters:
//   ply=URL        the scene, .ply or .spz (required)
//   camera=URL     a camera file: one camera, a list, or an orbit.json (its cameras[]),
//                  each {width, height, fx, fy, cx, cy, R (3 rows), t} with
//                  x_cam = R x_world + t in OpenCV axes (x right, y down, z forward)
//   index=N        which camera of the file (default 0)
//   bg=r,g,b       background in [0, 1], sRGB (default 0,0,0: render_orbit's default)
//   ext=0          Spark's compact encoding instead of the extended one (see below)
//   check          fixed-size canvas at the camera's exact intrinsics, no controls; sets
//                  window.viewerState.status to "ready" once the picture stops changing,
//                  and offers window.viewerCompare(refUrl) (PSNR + side-by-side picture)
// Without check the page is an orbit-controls viewer that starts at the camera (if given).
//
// Spark is set up for scenes trained the original 3DGS way, as orbitforge's are: the
// 0.3 px^2 low-pass dilation is added to the 2D covariance without rescaling opacity
// (preBlurAmount; Spark's default blurAmount rescales, as for anti-aliased training),
// splats are sorted by view-space depth (not radially), drawn out to 3 standard
// deviations, SH up to degree 3, and per-view colours above 1 are kept
// (accumExtSplats; 3DGS clamps colours at 0 only).
// The scene is stored in Spark's extended encoding (float32 positions, exact scales,
// colours above 1). Its SH coefficients lose precision there: Spark 2.2.0 stores each
// coefficient's RGB as a shared exponent floor(log2 max|c|) with 8-bit mantissas
// scaled by 255 / 2^exponent, so the largest channel saturates at 2^exponent (0.8
// reads back as 0.5). Trained scenes have small SH coefficients (|c| < 0.08 in a
// short pipeline run), where this costs little; ext=0 uses the compact encoding
// instead (half-float positions, 8-bit log scales, colours clamped to [0, 1], SH
// quantised to 7/8/6 bits over [-1, 1]), which measured 3.7 dB lower on such a scene.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { SparkRenderer, SplatMesh } from '@sparkjsdev/spark';

const query = new URLSearchParams(location.search);
const checkMode = query.has('check');
const info = document.getElementById('info');
const state = (window.viewerState = { status: 'loading', message: '' });

function fail(message) {
  if (state.status === 'error') return;
  state.status = 'error';
  state.message = message;
  info.textContent = message;
  console.error(message);
}
window.addEventListener('error', (e) => fail(`error: ${e.message}`));
window.addEventListener('unhandledrejection', (e) => fail(`error: ${(e.reason && e.reason.message) || e.reason}`));

function parseTriple(text, name) {
  const v = text.split(',').map(Number);
  if (v.length !== 3 || v.some((x) => !Number.isFinite(x))) throw new Error(`${name} expects x,y,z, got '${text}'`);
  return v;
}

async function fetchJson(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  try {
    return await r.json();
  } catch (e) {
    throw new Error(`${url}: not JSON (${e.message})`);
  }
}

function pickCamera(json, index, url) {
  const list = Array.isArray(json) ? json : Array.isArray(json.cameras) ? json.cameras : [json];
  if (!(Number.isInteger(index) && index >= 0 && index < list.length))
    throw new Error(`${url}: camera index ${index} outside 0..${list.length - 1}`);
  const c = list[index];
  for (const k of ['width', 'height', 'fx', 'fy', 'cx', 'cy', 'R', 't'])
    if (c[k] === undefined) throw new Error(`${url}: camera ${index} has no "${k}"`);
  const ok = Array.isArray(c.R) && c.R.length === 3 && c.R.every((row) => Array.isArray(row) && row.length === 3) &&
    Array.isArray(c.t) && c.t.length === 3;
  if (!ok) throw new Error(`${url}: camera ${index}: "R" must be 3 rows of 3 and "t" 3 values`);
  return c;
}

// A three.js camera with pinhole intrinsics (fx, fy, cx, cy of a width x height image),
// scaled to the canvas: the vertical field of view is kept, the principal point offset
// from the centre scales with it.
class IntrinsicsCamera extends THREE.PerspectiveCamera {
  constructor(k, near, far) {
    super(50, k.width / k.height, near, far);
    this.k = k;
    this.viewWidth = k.width;
    this.viewHeight = k.height;
    this.updateProjectionMatrix();
  }
  setViewSize(width, height) {
    this.viewWidth = width;
    this.viewHeight = height;
    this.updateProjectionMatrix();
  }
  updateProjectionMatrix() {
    if (!this.k) return super.updateProjectionMatrix();  // called by the base constructor
    const k = this.k, W = this.viewWidth, H = this.viewHeight, n = this.near, f = this.far;
    const s = H / k.height;
    const fx = k.fx * s, fy = k.fy * s;
    const cx = (k.cx - 0.5 * k.width) * s + 0.5 * W, cy = (k.cy - 0.5 * k.height) * s + 0.5 * H;
    this.fov = (2 * Math.atan(H / (2 * fy)) * 180) / Math.PI;  // Spark's level-of-detail code reads it
    this.aspect = W / H;
    // OpenGL clip space from pixel coordinates (y down, pixel i centred at i + 0.5) of a
    // camera looking down -z with y up.
    this.projectionMatrix.set(
      (2 * fx) / W, 0, 1 - (2 * cx) / W, 0,
      0, (2 * fy) / H, (2 * cy) / H - 1, 0,
      0, 0, -(f + n) / (f - n), (-2 * f * n) / (f - n),
      0, 0, -1, 0);
    this.projectionMatrixInverse.copy(this.projectionMatrix).invert();
  }
}

// Camera centre -R^T t; three.js axes are OpenCV's with y and z negated.
function placeCamera(camera, c) {
  const R = c.R, t = c.t;
  const centre = new THREE.Vector3(
    -(R[0][0] * t[0] + R[1][0] * t[1] + R[2][0] * t[2]),
    -(R[0][1] * t[0] + R[1][1] * t[1] + R[2][1] * t[2]),
    -(R[0][2] * t[0] + R[1][2] * t[1] + R[2][2] * t[2]));
  const x = new THREE.Vector3(...R[0]).normalize();
  const y = new THREE.Vector3(...R[1]).normalize().negate();
  const z = new THREE.Vector3(...R[2]).normalize().negate();
  camera.position.copy(centre);
  camera.quaternion.setFromRotationMatrix(new THREE.Matrix4().makeBasis(x, y, z));
  camera.up.copy(y);
  camera.updateMatrixWorld(true);
  return { centre, forward: z.clone().negate(), up: y };
}

async function main() {
  const ply = query.get('ply');
  if (!ply) throw new Error('no scene: open this page with ?ply=URL');
  const bg = parseTriple(query.get('bg') || '0,0,0', 'bg');
  if (bg.some((c) => c < 0 || c > 1)) throw new Error(`bg components must be in [0, 1], got ${bg}`);

  let cam = null, orbit = null;
  if (query.get('camera')) {
    const url = query.get('camera');
    const json = await fetchJson(url);
    cam = pickCamera(json, Number(query.get('index') || 0), url);
    orbit = json.orbit || null;
  } else if (checkMode) {
    throw new Error('check needs camera=URL');
  }

  const canvas = document.getElementById('view');
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, alpha: false, preserveDrawingBuffer: checkMode });
  const scene = new THREE.Scene();
  scene.background = new THREE.Color().setRGB(bg[0], bg[1], bg[2], THREE.SRGBColorSpace);
  const spark = new SparkRenderer({
    renderer,
    preBlurAmount: 0.3,
    blurAmount: 0,
    sortRadial: false,
    maxStdDev: 3,
    minAlpha: 1 / 255,
    accumExtSplats: true,
  });
  scene.add(spark);

  const k = cam || { width: 16, height: 9, fx: 12, fy: 12, cx: 8, cy: 4.5 };  // no camera: 41 deg vertical field of view
  const camera = new IntrinsicsCamera(k, 0.01, 1000);  // near = render_orbit's near plane

  info.textContent = `loading ${ply} ...`;
  const mesh = new SplatMesh({ url: ply, extSplats: query.get('ext') !== '0' });
  try {
    await mesh.initialized;
  } catch (e) {
    throw new Error(`${ply}: ${(e && e.message) || e}`);
  }
  // SPZ stores RUB axes (x right, y up, z back) and Spark draws its coordinates as
  // they are, where a PLY's are OpenCV's (y down, z forward): turning the SPZ mesh
  // half a turn about x puts both in the same world.
  if (/\.spz($|\?)/i.test(ply)) mesh.quaternion.set(1, 0, 0, 0);
  scene.add(mesh);
  const count = mesh.packedSplats?.numSplats ?? mesh.extSplats?.numSplats ?? mesh.splats?.numSplats;
  state.splats = count;

  if (checkMode) {
    renderer.setPixelRatio(1);
    renderer.setSize(cam.width, cam.height, false);
    canvas.style.width = `${cam.width}px`;
    canvas.style.height = `${cam.height}px`;
    document.body.classList.add('check');
    placeCamera(camera, cam);
    runCheck(renderer, scene, camera, cam.width, cam.height);
    return;
  }

  // Interactive viewer.
  let target;
  if (cam) {
    const pose = placeCamera(camera, cam);
    if (orbit && Array.isArray(orbit.look_at)) target = new THREE.Vector3(...orbit.look_at);
    else {
      const box = mesh.getBoundingBox(true);
      const d = box.getCenter(new THREE.Vector3()).sub(pose.centre).dot(pose.forward);
      target = pose.centre.clone().addScaledVector(pose.forward, d > 0 ? d : 1);
    }
    if (orbit && Array.isArray(orbit.normal)) camera.up.set(...orbit.normal).normalize();
  } else {
    // No camera: OpenCV-style data (y down), looking along +z at the splat centres.
    const box = mesh.getBoundingBox(true);
    target = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    camera.up.set(0, -1, 0);
    camera.position.copy(target).add(new THREE.Vector3(0, 0, -1.5 * size));
    camera.lookAt(target);
  }
  const controls = new OrbitControls(camera, canvas);
  controls.target.copy(target);
  controls.enableDamping = true;
  controls.update();

  function resize() {
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setSize(window.innerWidth, window.innerHeight);
    camera.setViewSize(window.innerWidth, window.innerHeight);
  }
  window.addEventListener('resize', resize);
  resize();
  renderer.setAnimationLoop(() => {
    controls.update();
    renderer.render(scene, camera);
  });
  state.status = 'ready';
  info.textContent = `${count ?? '?'} splats - drag: orbit, right-drag: pan, wheel: zoom`;
}

// Renders until the picture has stayed the same for 1.5 s and at least three checks two
// frames apart (Spark sorts and builds its splat list asynchronously), then stops and
// exposes the pixels.
function runCheck(renderer, scene, camera, W, H) {
  const gl = renderer.getContext();
  const readPixels = () => {
    renderer.setRenderTarget(null);
    const px = new Uint8Array(W * H * 4);
    gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, px);
    const out = new Uint8ClampedArray(W * H * 4);  // rows top to bottom
    for (let y = 0; y < H; ++y) out.set(px.subarray((H - 1 - y) * W * 4, (H - y) * W * 4), y * W * 4);
    return out;
  };
  const hash = (px) => {
    let h = 2166136261;
    for (let i = 0; i < px.length; ++i) h = Math.imul(h ^ px[i], 16777619);
    return h >>> 0;
  };
  const start = performance.now();
  let frames = 0, last = null, same = 0, since = start;
  renderer.setAnimationLoop(() => {
    renderer.render(scene, camera);
    ++frames;
    if (frames % 2 !== 0) return;
    const h = hash(readPixels());
    const now = performance.now();
    if (h === last) ++same;
    else {
      same = 0;
      since = now;
    }
    last = h;
    if (same >= 3 && now - since > 1500) {
      renderer.setAnimationLoop(null);
      state.frames = frames;
      state.settle_ms = Math.round(performance.now() - start);
      state.status = 'ready';
    }
  });

  window.viewerCompare = async (refUrl, scale = 1) => {
    const blob = await (await fetch(refUrl)).blob();
    const bmp = await createImageBitmap(blob, { colorSpaceConversion: 'none', premultiplyAlpha: 'none' });
    if (bmp.width !== W || bmp.height !== H)
      throw new Error(`${refUrl} is ${bmp.width}x${bmp.height}, the viewer drew ${W}x${H}`);
    const c2 = new OffscreenCanvas(W, H).getContext('2d', { colorSpace: 'srgb' });
    c2.drawImage(bmp, 0, 0);
    const ref = c2.getImageData(0, 0, W, H).data;
    const ours = readPixels();
    let se = 0, maxAbs = 0, off = 0;
    const bias = [0, 0, 0];
    const diff = new Uint8ClampedArray(W * H * 4);
    for (let i = 0; i < W * H; ++i) {
      let worst = 0;
      for (let c = 0; c < 3; ++c) {
        const d = ours[4 * i + c] - ref[4 * i + c];
        se += d * d;
        bias[c] += d;
        worst = Math.max(worst, Math.abs(d));
        diff[4 * i + c] = 4 * Math.abs(d);
      }
      diff[4 * i + 3] = 255;
      maxAbs = Math.max(maxAbs, worst);
      if (worst > 16) ++off;
    }
    const mse = se / (3 * W * H);
    // Side by side: viewer | orbitforge | 4 x |difference|, nearest-neighbour scaled.
    const gap = 4;
    const sheet = new OffscreenCanvas((3 * W + 2 * gap) * scale, H * scale);
    const ctx = sheet.getContext('2d');
    ctx.imageSmoothingEnabled = false;
    ctx.fillStyle = '#fff';
    ctx.fillRect(0, 0, sheet.width, sheet.height);
    const panels = [new ImageData(ours, W, H), new ImageData(new Uint8ClampedArray(ref), W, H), new ImageData(diff, W, H)];
    for (let p = 0; p < 3; ++p) {
      const bm = await createImageBitmap(panels[p]);
      ctx.drawImage(bm, p * (W + gap) * scale, 0, W * scale, H * scale);
    }
    const png = await sheet.convertToBlob({ type: 'image/png' });
    const shot = new OffscreenCanvas(W, H);
    shot.getContext('2d').putImageData(panels[0], 0, 0);
    const shotPng = await shot.convertToBlob({ type: 'image/png' });
    const b64 = async (b) => {
      const bytes = new Uint8Array(await b.arrayBuffer());
      let s = '';
      for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
      return btoa(s);
    };
    return {
      width: W,
      height: H,
      psnr: mse > 0 ? 10 * Math.log10((255 * 255) / mse) : Infinity,
      mean_signed_difference: bias.map((b) => b / (W * H)),
      max_abs_difference: maxAbs,
      pixels_off_by_more_than_16: off / (W * H),
      side_by_side_png: await b64(png),
      screenshot_png: await b64(shotPng),
    };
  };
}

main().catch((e) => fail(`error: ${e.message || e}`));
