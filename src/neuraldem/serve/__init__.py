"""`neuraldem serve`: an interactive explorer of the shipped models in the browser, one page per scene.

Built on Panel (HoloViz) with Plotly for the 3D particles and the curves. Why Panel, not trame: both serve a
Python app to the browser, but trame's VTK views need the `vtk` wheel (about 100 MB, and off-screen OpenGL
for its server-side rendering), while Panel and Plotly are pure-Python wheels that ship their JavaScript
(plotly.js included) and serve it from the app itself, so the page works with no internet. Plotly's
Scatter3d draws the few thousand particles of a hopper with WebGL in the browser, and Panel's widgets
(sliders, a player, text inputs) run Python callbacks over one websocket, which is what the latency budget
needs. Both are maintained (Panel by HoloViz, Plotly by Plotly Inc.), installed by the `serve` extra.

Pages are registered in `serve.app.PAGES` (route -> module): `hopper_page`, `fb_page`. Web code stays in the
page modules; the engines (`hopper_engine`, `fb_engine`) answer with no web code (the tests and the benchmark
call them directly).
"""
