// A form with data-confirm="question" is posted only once the question is answered OK. Here
// rather than in an onsubmit attribute: the dashboard's Content-Security-Policy runs no inline
// script (app/service/admin/headers.py).
"use strict";
document.addEventListener("submit", (event) => {
  const question = event.target.dataset && event.target.dataset.confirm;
  if (question && !window.confirm(question)) event.preventDefault();
});
