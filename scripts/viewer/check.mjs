// Headless check: Chromium (software WebGL, SwiftShader) draws a PLY with the viewer page
// at one camera; the picture is compared with orbitforge's own render of that camera.
//
//   node check.mjs --modules DIR --data DIR --ply NAME --camera NAME --ref NAME --out DIR
//                  [--index N] [--bg r,g,b] [--min-psnr 25] [--scale S] [--ext 0]
//
// NAMEs are paths inside --data; --ext 0 selects Spark's compact encoding (viewer.js).
// Writes OUT/viewer.png (the viewer's picture), OUT/side_by_side.png (viewer |
// orbitforge | 4 x |difference|, scaled S times) and OUT/result.json. Exit status:
// 0 pass, 1 mismatch or viewer error, 2 usage, 3 Chromium could not be started or has
// no WebGL2 (the caller decides whether to skip).
import fs from 'node:fs';
import path from 'node:path';
import { createRequire } from 'node:module';
import { pageQuery, parseArgs, startServer } from './server.mjs';

function usage(message) {
  console.error(`check.mjs: ${message}`);
  process.exit(2);
}

let args;
try {
  args = parseArgs(process.argv.slice(2),
                   ['modules', 'data', 'ply', 'camera', 'ref', 'out', 'index', 'bg', 'min-psnr', 'scale', 'ext']);
} catch (e) {
  usage(e.message);
}
for (const k of ['modules', 'data', 'ply', 'camera', 'ref', 'out']) if (!args[k]) usage(`--${k} is required`);
const minPsnr = Number(args['min-psnr'] ?? 25);
const scale = Number(args.scale ?? 1);
if (!Number.isFinite(minPsnr)) usage(`--min-psnr must be a number, got '${args['min-psnr']}'`);
if (!Number.isInteger(scale) || scale < 1 || scale > 8) usage(`--scale must be 1..8, got '${args.scale}'`);
if (args.ext !== undefined && args.ext !== '0' && args.ext !== '1') usage(`--ext must be 0 or 1, got '${args.ext}'`);
for (const k of ['ply', 'camera', 'ref'])
  if (!fs.existsSync(path.join(args.data, args[k]))) usage(`--${k}: ${path.join(args.data, args[k])} does not exist`);

const require = createRequire(path.join(path.resolve(args.modules), 'x.js'));
const { chromium } = require('playwright-core');
const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';

// Software WebGL only (SwiftShader through ANGLE); the network flags keep Chromium from
// reaching out (this machine refuses such connections). Playwright gives the browser a
// new, empty profile directory of its own.
const chromiumArgs = [
  '--no-sandbox',
  '--use-angle=swiftshader',
  '--enable-unsafe-swiftshader',
  '--ignore-gpu-blocklist',
  '--disable-quic',
  '--no-first-run',
  '--disable-background-networking',
  '--disable-component-update',
  '--disable-sync',
  '--disable-default-apps',
  '--disable-extensions',
  '--force-color-profile=srgb',
  '--force-device-scale-factor=1',
];

const t0 = Date.now();
const { server, origin } = await startServer({ modules: args.modules, data: args.data });
let browser;
try {
  browser = await chromium.launch({ executablePath, headless: true, args: chromiumArgs, timeout: 60000 });
} catch (e) {
  console.error(`check.mjs: cannot start ${executablePath}: ${e.message.split('\n')[0]}`);
  server.close();
  process.exit(3);
}
let exitCode = 1;
const log = [];
try {
  const page = await browser.newPage({ viewport: { width: 1024, height: 768 }, deviceScaleFactor: 1 });
  page.on('console', (m) => log.push(`[console.${m.type()}] ${m.text()}`));
  page.on('pageerror', (e) => log.push(`[pageerror] ${e.message}`));
  page.on('requestfailed', (r) => log.push(`[requestfailed] ${r.url()} ${r.failure()?.errorText}`));
  const gpu = await page.evaluate(() => {
    const gl = document.createElement('canvas').getContext('webgl2');
    if (!gl) return null;
    const ext = gl.getExtension('WEBGL_debug_renderer_info');
    return ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  });
  if (!gpu) {
    console.error('check.mjs: this Chromium has no WebGL2 (software WebGL unavailable)');
    exitCode = 3;
  } else {
    console.log(`webgl2 renderer: ${gpu}`);
    const query = pageQuery({
      ply: `/data/${args.ply}`,
      camera: `/data/${args.camera}`,
      index: args.index,
      bg: args.bg,
      check: 1,
      ext: args.ext,
    });
    const url = `${origin}/index.html?${query}`;
    console.log(`page: ${url}`);
    await page.goto(url);
    try {
      await page.waitForFunction(() => window.viewerState && window.viewerState.status !== 'loading', null,
                                 { timeout: 180000, polling: 200 });
    } catch (e) {
      throw new Error(`the viewer did not finish drawing: ${e.message.split('\n')[0]}`);
    }
    const st = await page.evaluate(() => window.viewerState);
    if (st.status !== 'ready') throw new Error(`viewer: ${st.message}`);
    const r = await page.evaluate(([ref, s]) => window.viewerCompare(ref, s), [`/data/${args.ref}`, scale]);
    fs.mkdirSync(args.out, { recursive: true });
    fs.writeFileSync(path.join(args.out, 'viewer.png'), Buffer.from(r.screenshot_png, 'base64'));
    fs.writeFileSync(path.join(args.out, 'side_by_side.png'), Buffer.from(r.side_by_side_png, 'base64'));
    const result = {
      psnr: r.psnr,
      min_psnr: minPsnr,
      width: r.width,
      height: r.height,
      splats: st.splats,
      mean_signed_difference: r.mean_signed_difference,
      max_abs_difference: r.max_abs_difference,
      pixels_off_by_more_than_16: r.pixels_off_by_more_than_16,
      frames_until_stable: st.frames,
      settle_ms: st.settle_ms,
      webgl_renderer: gpu,
      seconds: (Date.now() - t0) / 1000,
    };
    fs.writeFileSync(path.join(args.out, 'result.json'), JSON.stringify(result, null, 2) + '\n');
    const f = (x) => x.toFixed(2);
    console.log(`viewer vs orbitforge: PSNR ${f(r.psnr)} dB (pass at >= ${minPsnr}), ${r.width}x${r.height}, ` +
                `${st.splats} splats; mean signed difference (0-255) R ${f(r.mean_signed_difference[0])} ` +
                `G ${f(r.mean_signed_difference[1])} B ${f(r.mean_signed_difference[2])}; ` +
                `max |difference| ${r.max_abs_difference}; ${f(100 * r.pixels_off_by_more_than_16)} % of pixels ` +
                `off by more than 16; stable after ${st.frames} frames / ${st.settle_ms} ms`);
    exitCode = r.psnr >= minPsnr ? 0 : 1;
  }
} catch (e) {
  console.error(`check.mjs: ${e.message}`);
  exitCode = 1;
} finally {
  if (exitCode !== 0 && log.length) console.error(log.slice(-20).join('\n'));
  await browser.close();
  server.close();
}
process.exit(exitCode);
