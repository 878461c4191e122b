// Builds ../plotly-raim.min.js from entry.js, with plotly.js's own esbuild settings
// (plotly.js/esbuild-config.js) less the WebGL plugin no panel needs.
const esbuild = require('esbuild');
const { environmentPlugin } = require('esbuild-plugin-environment');
const InlineCSSPlugin = require('esbuild-plugin-inline-css');
const version = require('plotly.js/package.json').version;
esbuild.build({
  entryPoints: [`${__dirname}/entry.js`],
  outfile: `${__dirname}/../plotly-raim.min.js`,
  format: 'iife',
  globalName: 'Plotly',
  bundle: true,
  minify: true,
  legalComments: 'none',
  banner: {js: `/* plotly.js v${version} (MIT license, Copyright Plotly, Inc.): partial bundle ` +
                `of RAIM Studio (core, bar, heatmap, contour, scatterpolar), app/assets/plotly */`},
  footer: {js: 'window.Plotly = Plotly;'},
  plugins: [InlineCSSPlugin(), environmentPlugin({ NODE_DEBUG: false })],
  alias: { regl: '@plotly/regl', stream: 'stream-browserify' },
  define: { global: 'window', 'define.amd': 'false' },
  target: 'es2016',
  logLevel: 'info',
}).catch(() => process.exit(1));
