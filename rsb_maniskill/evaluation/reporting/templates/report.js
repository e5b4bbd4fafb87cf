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
    c.appendChild(el("div", "tags", tags));
    const instr = el("div", "instr", ep.instruction || "(blank instruction)");
    instr.title = "click to expand";
    instr.addEventListener("click", () => instr.classList.toggle("open"));
    c.appendChild(instr);
    c.appendChild(candidate("correct", ep.correct));
    c.appendChild(candidate("grasped", ep.grasped));
    if (ep.said !== null && ep.said !== undefined) {
      const said = el("div", "instr said", "said: " + (ep.said || "(nothing)"));
      said.title = "the policy's text; click to expand";
      said.addEventListener("click", () => said.classList.toggle("open"));
      c.appendChild(said);
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
        img.title = "first / last frame; click to play the video";
        img.addEventListener("click", () => {
          const v = el("video");
          v.src = ep.video; v.controls = true; v.autoplay = true; v.muted = true;
          media.replaceChildren(v);
        });
        media.appendChild(img);
      });
      c.appendChild(media);
    } else {
      c.appendChild(el("div", "novideo", "no video recorded (rsb eval --videos K)"));
    }
    return c;
  }
  function showMore() {
    const frag = document.createDocumentFragment();
    matching.slice(shown, shown + PAGE).forEach(ep => frag.appendChild(card(ep)));
    grid.appendChild(frag);
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
  selects.forEach(s => s.addEventListener("change", apply));
  more.addEventListener("click", showMore);
  apply();
})();
