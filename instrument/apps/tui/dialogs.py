"""Modal dialogs: a yes/no question, a choice among a few answers, a one-line input with validation, a message;
and the main screen's own: resume or replace earlier results, the tolerance, a results directory to overlay.

The question, the choice and the message pass two of the app's keys on: ``q`` quits (the app asks first
while a sweep runs) and ``a`` aborts a running sweep (``APP_KEYS`` names them, so the app's footer shows what
works). The input dialog passes none: every printable key is typed (Ctrl+Q, the app's, quits everywhere).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from textual import events
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Input, Static

from bodebench.apps.tui.files import load_results
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import AnalysisConfig
from bodebench.io.results import ResultsError
from bodebench.io.schema import check_value

DIALOG_CSS = """
.dialog-box { width: 70; max-width: 95%; height: auto; max-height: 90%; padding: 1 2;
              border: thick $primary; background: $surface; }
.dialog-box.-error { border: thick $error; }
.dialog-title { text-style: bold; margin-bottom: 1; }
.dialog-buttons { height: auto; margin-top: 1; align-horizontal: right; }
.dialog-buttons Button { margin-left: 1; }
.dialog-error { color: $error; height: auto; }
"""


APP_BINDINGS = [Binding("q", "app.request_quit", "quit", show=False),
                Binding("a", "app.abort", "abort", show=False)]
"""The app's keys a dialog passes on (see the module docstring)."""


class ConfirmDialog(ModalScreen[bool]):
    """A question answered yes (y) or no (n, escape)."""

    DEFAULT_CSS = "ConfirmDialog { align: center middle; }\n" + DIALOG_CSS
    BINDINGS = [Binding("y", "answer(True)", "yes"), Binding("n", "answer(False)", "no"),
                Binding("escape", "answer(False)", "no", show=False), *APP_BINDINGS]
    APP_KEYS = ("request_quit", "abort")

    def __init__(self, question: str, yes: str = "Yes") -> None:
        super().__init__()
        self.question = question
        self.yes = yes

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog-box"):
            yield Static(self.question, classes="dialog-title")
            with Horizontal(classes="dialog-buttons"):
                yield Button(f"{self.yes} (y)", variant="error", id="yes")
                yield Button("No (n)", id="no")

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.dismiss(event.button.id == "yes")

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)


class ChoiceDialog(ModalScreen["str | None"]):
    """A question with a few answers, each a button and a key: ``choices`` are (answer, label, key, variant); the
    answer is dismissed with, escape answers None (the last choice should say so, for example Cancel)."""

    DEFAULT_CSS = "ChoiceDialog { align: center middle; }\n" + DIALOG_CSS
    BINDINGS = [Binding("escape", "choose(None)", "cancel", show=False), *APP_BINDINGS]
    APP_KEYS = ("request_quit", "abort")

    def __init__(self, question: str, choices: Sequence[tuple[str | None, str, str, str]]) -> None:
        super().__init__()
        self.question = question
        self.choices = list(choices)
        taken = {b.key for b in self.BINDINGS if isinstance(b, Binding)}
        keys = [key for _, _, key, _ in self.choices]
        if len(set(keys)) != len(keys) or taken & set(keys):
            raise ValueError(f"each choice needs its own key, not one of {sorted(taken)}: {keys}")

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog-box"):
            yield Static(self.question, classes="dialog-title", id="dialog-text")
            with Horizontal(classes="dialog-buttons"):
                for i, (_, label, key, variant) in enumerate(self.choices):
                    yield Button(f"{label} ({key})", variant=variant, id=f"choice-{i}")  # type: ignore[arg-type]

    def on_key(self, event: events.Key) -> None:
        for answer, _, key, _ in self.choices:
            if event.key == key:
                event.stop()
                self.dismiss(answer)
                return

    def on_button_pressed(self, event: Button.Pressed) -> None:
        index = int((event.button.id or "choice-0").removeprefix("choice-"))
        self.dismiss(self.choices[index][0])

    def action_choose(self, answer: str | None) -> None:
        self.dismiss(answer)


class EarlierResultsDialog(ChoiceDialog):
    """Results are already where a new sweep would write (``where``): resume them (r), replace them (x) or cancel
    (c); ``refused`` says why they cannot be resumed (then only replace or cancel)."""

    def __init__(self, where: str, refused: str = "") -> None:
        if refused:
            super().__init__(f"Results are already in {where}, and cannot be resumed: {refused}. Replace them with a "
                             "new sweep?", [("replace", "Replace", "x", "error"), (None, "Cancel", "c", "default")])
        else:
            super().__init__(f"Results are already in {where}. Resume measures only the missing frequencies and keeps "
                             "the others; replace starts again and overwrites them.",
                             [("resume", "Resume", "r", "primary"), ("replace", "Replace", "x", "error"),
                              (None, "Cancel", "c", "default")])


class InputDialog(ModalScreen["str | None"]):
    """One line of input; ``validate`` returns an error text (shown, the dialog stays) or None to accept.
    Escape cancels (None)."""

    DEFAULT_CSS = "InputDialog { align: center middle; }\n" + DIALOG_CSS
    BINDINGS = [Binding("escape", "cancel", "cancel", show=False)]

    def __init__(self, prompt: str, value: str = "", validate: Callable[[str], str | None] | None = None,
                 placeholder: str = "") -> None:
        super().__init__()
        self.prompt = prompt
        self.value = value
        self.validate = validate or (lambda text: None)
        self.placeholder = placeholder

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog-box"):
            yield Static(self.prompt, classes="dialog-title")
            yield Input(self.value, placeholder=self.placeholder, id="dialog-input")
            yield Static("", classes="dialog-error", id="dialog-error")
            yield Static("enter: accept   escape: cancel", classes="dialog-hint")

    def on_mount(self) -> None:
        self.query_one(Input).focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        text = event.value.strip()
        error = self.validate(text)
        if error:
            self.query_one("#dialog-error", Static).update(error)
            return
        self.dismiss(text)

    def action_cancel(self) -> None:
        self.dismiss(None)


class ToleranceDialog(InputDialog):
    """The tolerance for the next points (%), starting from ``current``; a value [analysis] would refuse is
    refused with the reason."""

    def __init__(self, current: float) -> None:
        super().__init__("Tolerance for the next points (%)", f"{current:g}", self.problem)

    @staticmethod
    def problem(text: str) -> str | None:
        """Why ``text`` is no tolerance (None: it is one)."""
        try:
            value = float(text)
        except ValueError:
            return f"not a number: {text!r}"
        problem = check_value(AnalysisConfig, "tolerance_percent", value)
        return f"the tolerance {problem}" if problem else None


class OverlayDialog(InputDialog):
    """A results directory (or a directory of them) to overlay on the Bode plot, starting from ``start``; once
    accepted, ``loaded`` holds its responses, (label, response)."""

    def __init__(self, start: str) -> None:
        super().__init__("Open a results directory to overlay on the Bode plot", start, self.load,
                         placeholder="path/to/results")
        self.loaded: list[tuple[str, FrequencyResponse]] = []

    def load(self, text: str) -> str | None:
        """Load the responses in the directory ``text``; what is wrong with it (None: nothing)."""
        if not text:
            return "enter a results directory"
        try:
            self.loaded = load_results(Path(text).expanduser())
        except ResultsError as exc:
            return str(exc)
        return None


class MessageDialog(ModalScreen[None]):
    """A message (an error: red border) closed with enter or escape."""

    DEFAULT_CSS = "MessageDialog { align: center middle; }\n" + DIALOG_CSS
    BINDINGS = [Binding("escape", "close", "close", show=False), Binding("enter", "close", "close", show=False),
                *APP_BINDINGS]
    APP_KEYS = ("request_quit", "abort")

    def __init__(self, title: str, text: str, error: bool = False) -> None:
        super().__init__()
        self.title_text = title
        self.text = text
        self.error = error

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog-box -error" if self.error else "dialog-box"):
            yield Static(self.title_text, classes="dialog-title")
            yield Static(self.text, id="dialog-text")
            with Horizontal(classes="dialog-buttons"):
                yield Button("OK", variant="primary", id="ok")

    def on_mount(self) -> None:
        self.query_one("#ok", Button).focus()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.dismiss(None)

    def action_close(self) -> None:
        self.dismiss(None)
