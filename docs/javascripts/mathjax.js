// Pages written in Markdown: pymdownx.arithmatex wraps each formula in an
// element of class "arithmatex" with \( \) or \[ \] delimiters.  Notebooks
// (mkdocs-jupyter): their Markdown cells keep $ $ and $$ $$ formulas as text,
// inside elements of class "jp-MarkdownOutput".  Only those two kinds of
// element are typeset, so a dollar sign anywhere else stays a dollar sign.
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"], ["$", "$"]],
    displayMath: [["\\[", "\\]"], ["$$", "$$"]],
    processEscapes: true,
    processEnvironments: true,
  },
  options: {
    ignoreHtmlClass: ".*|",
    processHtmlClass: "arithmatex|jp-MarkdownOutput",
  },
};

document$.subscribe(() => {
  MathJax.typesetPromise();
});
