(function () {
  "use strict";
  const episodes = JSON.parse(document.getElementById("episode-data").textContent);
  const style = JSON.parse(document.getElementById("report-style").textContent);
  const grid = document.getElementById("grid"), more = document.getElementById("more");
  const count = document.getElementById("count");
  const selects = Array.from(document.querySelectorAll("select[data-filter]"));
  const PAGE = 120;
  let shown = 0, matching = [];

  function el(tag, cls, text) {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function candidate(label, c) {
    const p = el("div", "cand");
    p.appendChild(el("b", "", label));
    const text = c ? c.letter + " \u00b7 " + c.block + (c.option ? " \u2014 " + c.option : "") : "none";
    p.appendChild(document.createTextNode(text));
    return p;
  }
  // A text the card shows in five lines at most, and a button to read it whole (hidden when it fits).
  function clamped(parent, cls, text, what) {
    const shown = el("div", cls, text);
    const more = el("button", "expand", "show the whole " + what);
    more.type = "button";
    more.addEventListener("click", () => {
      const open = shown.classList.toggle("open");
      more.textContent = open ? "show less" : "show the whole " + what;
    });
    parent.appendChild(shown);
    parent.appendChild(more);
  }
  // The "show the whole ..." button only under a text the card cuts; measured once laid out, and
  // again when the grid's width changes (the text wraps anew).
  function measure() {
    grid.querySelectorAll(".expand").forEach(b => {
      const text = b.previousElementSibling;
      if (!text.classList.contains("open")) b.hidden = text.scrollHeight <= text.clientHeight + 1;
    });
  }
  let lastWidth = 0;
  new ResizeObserver(entries => {
    const w = entries[0].contentRect.width;
    if (w !== lastWidth) { lastWidth = w; measure(); }
  }).observe(grid);
  function cutNote(ep) {
    const kept = (ep.said || "").length;
    return ep.said_chars && ep.said_chars > kept ?
      "\n[the record keeps the first " + kept + " of " + ep.said_chars + " characters]" : "";
  }
  function card(ep) {
    const color = style.colors[ep.outcome];
    const c = el("article", "card");
    c.style.borderTopColor = color;
    c.dataset.outcome = ep.outcome;
    const top = el("div", "top");
    top.appendChild(el("span", "id", ep.suite + " \u00b7 seed " + ep.seed));
    const badge = el("span", "badge", style.labels[ep.outcome]);
    badge.style.background = color;
    top.appendChild(badge);
    c.appendChild(top);
    let tags = ep.policy + " \u00b7 " + ep.mode + " instruction";
    if (ep.steps != null) tags += " \u00b7 " + ep.steps + " steps";
    if (ep.donor_seed != null) tags += " \u00b7 text of seed " + ep.donor_seed;
    if (ep.variant != null) tags += " \u00b7 variant " + ep.variant + (ep.variant_kind ? " (" + ep.variant_kind + ")" : "");
    c.appendChild(el("div", "tags", tags));
    if (ep.kinds && ep.kinds.length) c.appendChild(el("div", "kinds", ep.kinds.join(" \u00b7 ")));
    clamped(c, "instr", ep.instruction || "(blank instruction)", "instruction");
    c.appendChild(candidate("correct", ep.correct));
    c.appendChild(candidate("grasped", ep.grasped));
    if (ep.said !== null && ep.said !== undefined) {
      clamped(c, "instr said", "said: " + (ep.said || "(nothing)") + cutNote(ep), "text");
      const right = ep.correct && ep.stated === ep.correct.letter;
      const states = el("div", "cand");
      states.appendChild(el("b", "", "states"));
      states.appendChild(document.createTextNode(ep.stated ? ep.stated + (right ? " (right)" : " (wrong)")
                                                           : "no option"));
      c.appendChild(states);
    }
    if (ep.thumbs) {
      const media = el("div", "media");
      ep.thumbs.forEach((src, i) => {
        const img = el("img");
        img.src = src;
        img.alt = (i ? "last" : "first") + " frame";
        img.title = (i ? "last" : "first") + " frame; click to see it at full resolution";
        img.addEventListener("click", () => openLightbox(ep, i));
        media.appendChild(img);
      });
      c.appendChild(media);
      const play = el("button", "play", "\u25b6 play video");
      play.type = "button";
      play.addEventListener("click", () => {
        const v = el("video");
        v.src = ep.video; v.controls = true; v.autoplay = true; v.muted = true;
        media.replaceChildren(v);
        play.remove();
      });
      c.appendChild(play);
    } else {
      c.appendChild(el("div", "novideo", "no video recorded (rsb eval --videos K)"));
    }
    return c;
  }
  function showMore() {
    const frag = document.createDocumentFragment();
    matching.slice(shown, shown + PAGE).forEach(ep => frag.appendChild(card(ep)));
    grid.appendChild(frag);
    measure();
    shown = Math.min(matching.length, shown + PAGE);
    more.hidden = shown >= matching.length;
    count.textContent = matching.length + " of " + episodes.length + " episodes" +
      (shown < matching.length ? " (showing " + shown + ")" : "");
  }
  function apply() {
    const want = {};
    selects.forEach(s => { if (s.value) want[s.dataset.filter] = s.value; });
    matching = episodes.filter(ep => Object.keys(want).every(k => String(ep[k]) === want[k]));
    grid.replaceChildren();
    shown = 0;
    showMore();
  }
  // The lightbox: a frame at the video's resolution (the 10-choice blocks' letters readable), the
  // episode's whole instruction and text, and its video.
  const box = document.getElementById("lightbox"), boxMedia = document.getElementById("lb-media");
  const boxImg = document.getElementById("lb-img"), play = document.getElementById("lb-play");
  const frameButtons = Array.from(box.querySelectorAll("button[data-frame]"));
  let boxEp = null;
  function showFrame(i) {
    boxImg.src = boxEp.thumbs[i];
    boxImg.alt = (i ? "last" : "first") + " frame of " + boxEp.suite + " seed " + boxEp.seed;
    boxMedia.replaceChildren(boxImg);
    frameButtons.forEach(b => b.setAttribute("aria-pressed", String(Number(b.dataset.frame) === i)));
  }
  function openLightbox(ep, i) {
    boxEp = ep;
    document.getElementById("lb-title").textContent =
      ep.suite + " \u00b7 seed " + ep.seed + " \u00b7 " + ep.policy + " \u00b7 " + style.labels[ep.outcome];
    let text = "instruction: " + (ep.instruction || "(blank)");
    if (ep.said !== null && ep.said !== undefined) text += "\n\nsaid: " + (ep.said || "(nothing)") + cutNote(ep);
    document.getElementById("lb-text").textContent = text;
    showFrame(i);
    if (!box.open) box.showModal();
  }
  frameButtons.forEach(b => b.addEventListener("click", () => showFrame(Number(b.dataset.frame))));
  play.addEventListener("click", () => {
    const v = el("video");
    v.src = boxEp.video; v.controls = true; v.autoplay = true; v.muted = true;
    boxMedia.replaceChildren(v);
    frameButtons.forEach(b => b.setAttribute("aria-pressed", "false"));
  });
  document.getElementById("lb-close").addEventListener("click", () => box.close());
  box.addEventListener("click", e => { if (e.target === box) box.close(); });  // a click on the backdrop
  box.addEventListener("close", () => boxMedia.replaceChildren(boxImg));  // stops a playing video
  selects.forEach(s => s.addEventListener("change", apply));
  more.addEventListener("click", showMore);
  apply();
})();
