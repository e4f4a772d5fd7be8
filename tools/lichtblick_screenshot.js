// The README's live-view screenshot: Lichtblick (the open-source Foxglove Studio) connected to a
// flying run's live view, with docs/lichtblick-layout.json imported through Layouts > Import from file.
//
// How docs/img/lichtblick-live.png was made (Lichtblick 1.10.8, Debian chromium, playwright-core):
//   1. Lichtblick from source: git clone, `corepack yarn install` (YARN_NPM_REGISTRY_SERVER=
//      https://registry.npmjs.org, ELECTRON_SKIP_BINARY_DOWNLOAD=1), then
//      `node_modules/.bin/webpack --mode development --config web/webpack.config.ts`. Its fonts
//      (packages/suite-base/src/styles/assets/*.woff2) are Git LFS pointers in a plain clone, and the
//      app does not start without them: copy Inter and IBM Plex Mono from the npm packages
//      @fontsource/inter and @fontsource/ibm-plex-mono over them first.
//   2. Serve web/.webpack: `python3 -m http.server 8080 --bind 127.0.0.1` in that folder.
//   3. Fly: `scenenav run scenarios/demo.yaml --out RUN --live --set clock.mode=realtime`.
//   4. `node tools/lichtblick_screenshot.js \
//        "http://127.0.0.1:8080/?ds=foxglove-websocket&ds.url=ws://127.0.0.1:8765" OUT.png \
//        docs/lichtblick-layout.json 3 35000`
//      writes OUT-0.png, OUT-1.png, ... 35 s apart. NODE_PATH must reach playwright-core.
//
// The browser's file picker cannot be driven headless, so window.showOpenFilePicker answers with the
// layout file; everything after it (Lichtblick parsing and selecting the layout) is the app's own.
const { chromium } = require('playwright-core');
const fs = require('fs');
const [url, out, layoutPath, n, waitMs] = process.argv.slice(2);
(async () => {
  const layout = fs.readFileSync(layoutPath, 'utf8');
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    args: ['--no-sandbox', '--use-gl=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
  });
  const page = await browser.newPage({ viewport: { width: 1600, height: 1000 } });
  page.on('console', (m) => { if (m.type() === 'error') console.log('console', m.text().slice(0, 300)); });
  page.on('pageerror', (e) => console.log('pageerror', String(e).slice(0, 300)));
  await page.addInitScript((l) => {
    window.showOpenFilePicker = async () =>
      [{ getFile: async () => new File([l], 'scenenav.json', { type: 'application/json' }) }];
  }, layout);
  await page.goto(url, { waitUntil: 'load', timeout: 120000 });
  await page.waitForTimeout(5000);
  await page.getByText('Layouts', { exact: true }).click();
  await page.waitForTimeout(1000);
  await page.getByText('Import from file…').or(page.getByText('Import from file...')).first().click();
  await page.waitForTimeout(1500);
  for (const label of ['Discard changes', 'Discard', "Don't save"]) {   // the default layout's edits
    const b = page.getByRole('button', { name: label });
    if (await b.count()) { await b.first().click(); break; }
  }
  await page.waitForTimeout(3000);
  await page.locator('button[aria-label="Close"], [data-testid="CloseIcon"]').first().click().catch(() => {});
  for (let i = 0; i < Number(n); i++) {
    await page.waitForTimeout(Number(waitMs));
    await page.screenshot({ path: out.replace('.png', `-${i}.png`) });
  }
  await browser.close();
})();
