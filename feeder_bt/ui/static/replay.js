// feeder replay FILE.db --ui: the tree view over a past run (no login, read only).
"use strict";
window.feederTree.mount(document.getElementById("tree-view"), false).start();
