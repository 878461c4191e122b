// The dashboard's plotly.js: the core (scatter) and the trace types its panels use.
// A new trace type in app/ needs its module here and a rebuild (README.md beside this file).
'use strict';
var Plotly = require('plotly.js/lib/core');
Plotly.register([
    require('plotly.js/lib/bar'),
    require('plotly.js/lib/heatmap'),
    require('plotly.js/lib/contour'),
    require('plotly.js/lib/scatterpolar'),
]);
module.exports = Plotly;
