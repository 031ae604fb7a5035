"""LMR's reference for ``bench_filters_ref.py --ref lmr=DIR``: the authors' MATLAB code under GNU Octave.

``DIR`` is a checkout of StaRainJ/LMR (Ma, Jiang, Jiang, Zhao, Guo, "LMR: learning a two-class classifier for
mismatch removal", IEEE TIP 2019), outside this repository, read at run time and never copied. Its
``LMR_Test.m`` sets the neighbourhood sizes ``Klist``, builds the match representations with ``MPC.m``
(``feature = MPC(Xt, Yt, Klist)``, 48 columns) and classifies them with the trained two-output network of
``Trained_Model/Net.mat`` (the demo's default among the network, random forest and SVM): a match is kept when
the first output exceeds the second (``testVal0(:, 1) > testVal0(:, 2)``).

What the driver adds, because Octave lacks two MATLAB toolboxes:

- ``gaussmf`` (Fuzzy Logic Toolbox), which ``MPC.m`` calls: written into the run's temp dir as its documented
  formula ``exp(-(x - c)^2 / (2 sigma^2))`` with ``params = [sigma c]``;
- the network's forward pass (Deep Learning Toolbox, ``net(x')``): ``Net.mat`` loads in Octave as a plain
  struct (Octave has no ``network`` class); the driver checks that it has no input or output processing
  functions and evaluates ``a_1 = f_1(IW{1,1} x + b{1})``, ``a_l = f_l(LW{l,l-1} a_(l-1) + b{l})`` with each
  layer's ``transferFcn`` (``tansig``, ``logsig`` or ``purelin``, by their definitions). The network is loaded
  before the timed block (our filter's model is loaded once per process too).

VLFeat's ``vl_kdtreebuild`` / ``vl_kdtreequery`` (``MPC.m``'s neighbour searches) are compiled from the
checkout's ``vlfeat`` sources as for LPM. ``Klist`` is read from ``LMR_Test.m`` at run time.
"""

from __future__ import annotations

from pathlib import Path

#: bench_filters_ref's shared helpers, set by ``bench_filters_ref.plugin`` before this module runs.
host: object

#: Files a checkout must hold.
FILES = ("LMR_Test.m", "MPC.m", "Net.mat", "vl_kdtreebuild.c", "kdtree.c")

#: Files whose folders go on Octave's path.
FUNC_FILES = ("MPC.m",)

#: No option of our ``lmr_filter`` exists in the authors' code (their constants are fixed in MPC.m).
OPTIONS: dict = {}

_GAUSSMF = """function y = gaussmf(x, params)
% Gaussian membership function, as documented: exp(-(x - c)^2 / (2 sigma^2)), params = [sigma c].
y = exp(-(x - params(2)) .^ 2 / (2 * params(1) ^ 2));
end
"""

# The forward pass of a feed-forward network loaded as a struct (see the module notes).
_NET_FORWARD = r"""
lmr_tf = struct('tansig', @(n) 2 ./ (1 + exp(-2 * n)) - 1, 'logsig', @(n) 1 ./ (1 + exp(-n)), ...
                'purelin', @(n) n);
if ~isempty(lmr_net.inputs{1}.processFcns) || ~isempty(lmr_net.outputs{end}.processFcns)
  error('Net.mat: processing functions are not supported by this driver');
end
a = feature';
for l = 1:lmr_net.numLayers
  if l == 1, w = lmr_net.IW{1, 1}; else, w = lmr_net.LW{l, l - 1}; end
  a = lmr_tf.(lmr_net.layers{l}.transferFcn)(w * a + lmr_net.b{l});
end
testVal0 = a';
"""


def klist_line(demo: str) -> str:
    """The ``Klist = [...];`` statement of ``LMR_Test.m`` (possibly continued over lines with ``...``)."""
    lines = demo.splitlines()
    for i, ln in enumerate(lines):
        s = ln.strip()
        if s.startswith("Klist") and "=" in s:
            out = [s]
            j = i
            while "]" not in lines[j]:
                j += 1
                out.append(lines[j].strip())
            return "\n".join(out)
    raise ValueError("LMR_Test.m: no Klist = [...] line")


def octave_body(root: Path, params: dict) -> str:
    """Body of ``ref_filter(X, Y, small, info)``: ``Klist`` from the demo, ``MPC``, the network of
    ``Net.mat``; ``keep`` = the rows whose first output exceeds the second; ``cpu`` around MPC and the net."""
    root = Path(root)
    klist = klist_line(host.find_reference_file(root, "LMR_Test.m").read_text(errors="replace"))
    net = host.find_reference_file(root, "Net.mat")
    return (f"persistent lmr_net\nif isempty(lmr_net)\n  warning('off', 'all');\n  s = load('{net}');\n"
            f"  lmr_net = s.net;\nend\n{klist}\nc0 = cputime;\nXt = X'; Yt = Y';\n"
            f"feature = MPC(Xt, Yt, Klist);\n{_NET_FORWARD}\n"
            "keep = find(testVal0(:, 1) > testVal0(:, 2));\ncpu = cputime - c0;")


def compile_mex(root: Path, dst: Path) -> None:
    """VLFeat's k-d tree from the checkout (as for LPM) and the ``gaussmf`` stand-in, into ``dst``."""
    host.compile_octave_mex("lpm", Path(root), dst)
    (Path(dst) / "gaussmf.m").write_text(_GAUSSMF)
