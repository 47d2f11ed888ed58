"""A private nbgrader exchange for a machine many students share (a JupyterHub whose
spawner runs each student's server as their own Unix user).

nbgrader's default exchange is one world-writable folder: whoever learns the name of a
submission (or of a feedback page) can read, replace or delete it. Here every student has
two folders of their own, made by root from the roster (:func:`set_up`, the command
``cobotlab course exchange``)::

    ROOT/                      root:root     0755   nobody but root adds or renames here
    ROOT/COURSE/               root:root     0755
    ROOT/COURSE/outbound/      root:STAFF    2775   instructors release, everyone fetches
    ROOT/COURSE/inbound/       root:STAFF    0751   instructors list; students only pass
    ROOT/COURSE/inbound/SID/   SID:STAFF     2750   SID hands in; instructors read
    ROOT/COURSE/feedback/      root:STAFF    0751
    ROOT/COURSE/feedback/SID/  SID:STAFF     2570   instructors write; SID reads

The classes below are nbgrader's own exchange operations (``nbgrader fetch_assignment``,
``submit``, ``list``, ``fetch_feedback``, ``release_assignment``, ``collect``,
``release_feedback``, and the JupyterLab Assignments tab, which calls the same classes),
chosen in ``nbgrader_config.py`` through ``c.ExchangeFactory`` (:func:`config_block`) and
changed only where the layout differs: a student reads and writes only the folders named
after their own Unix user (never the name they claim), and the instructors' side copies
what students wrote without following a link. docs/exchange.md says what each mode
defends and what is left.

This module runs in every student's server: it imports nbgrader, the standard library and
:mod:`autograder.safe_files` only.
"""

from __future__ import annotations

import glob
import grp
import os
import pwd
import re
import secrets
import shutil
import stat
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

from nbgrader.exchange import default
from nbgrader.utils import ignore_patterns, notebook_hash

from autograder.roster import roster_ids
from autograder.safe_files import Refused, TreeCaps, copy_tree, open_folder

__all__ = ["MODES", "set_up", "read_roster", "config_block", "write_config", "layout_problem",
           "PrivateExchange", "PrivateFetchAssignment", "PrivateSubmit", "PrivateList",
           "PrivateCollect", "PrivateReleaseAssignment", "PrivateReleaseFeedback",
           "PrivateFetchFeedback"]

INBOUND, OUTBOUND, FEEDBACK = "inbound", "outbound", "feedback"
# (owner, group, mode) of each folder; "root", "staff" or "student" (the folder's own).
MODES = {
    "root": ("root", "root", 0o755),
    "course": ("root", "root", 0o755),
    OUTBOUND: ("root", "staff", 0o2775),
    INBOUND: ("root", "staff", 0o751),
    FEEDBACK: ("root", "staff", 0o751),
    f"{INBOUND}/SID": ("student", "staff", 0o2750),
    f"{FEEDBACK}/SID": ("student", "staff", 0o2570),
}
# A submission as its student leaves it: the instructors' group reads, nobody else.
_SUBMITTED_FILE, _SUBMITTED_DIR = 0o640, 0o750
# Released files: every instructor may replace them (release --force), everyone reads.
_RELEASED_FILE, _RELEASED_DIR = 0o664, 0o2775
_CLOCK_SLACK = timedelta(minutes=5)   # servers' clocks and slow copies
_FEEDBACK_FILE = 0o644   # read through feedback/SID/, which only SID and staff enter
_NAME = re.compile(r"[a-z_][a-z0-9_.-]*\$?", re.I)   # a Unix user name (no '+', '*', '/')
_BEGIN, _END = "# >>> cobotlab private exchange >>>", "# <<< cobotlab private exchange <<<"
_CLASSES = {"exchange": "PrivateExchange", "fetch_assignment": "PrivateFetchAssignment",
            "fetch_feedback": "PrivateFetchFeedback",
            "release_assignment": "PrivateReleaseAssignment",
            "release_feedback": "PrivateReleaseFeedback", "list": "PrivateList",
            "submit": "PrivateSubmit", "collect": "PrivateCollect"}
_SETUP = "sudo cobotlab course exchange ROOT --students ROSTER --instructors GROUP"


# ------------------------------------------------------------------------------ the set-up


def read_roster(path) -> list[str]:
    """The student ids of a roster (:mod:`autograder.roster`'s format: a CSV file with an
    ``id`` column, the file ``nbgrader db student import`` takes), each id a student's Unix
    user name."""
    return roster_ids(path)


@dataclass
class SetUp:
    """What :func:`set_up` did: folders made or corrected, and warnings for the admin."""

    changed: list[str]
    warnings: list[str]


def set_up(root, students, instructors: str, course_id: str = "cobotlab") -> SetUp:
    """Make (or correct) the private exchange's folders for ``course_id`` under ``root``:
    one inbound and one feedback folder per student of ``students`` (Unix user names),
    readable by the Unix group ``instructors``, as :data:`MODES` says. Run as root; safe to
    run again (after adding students to the roster). Raises ValueError, naming the fix,
    before changing anything if the machine is not ready for it."""
    if os.geteuid() != 0:
        raise ValueError("the private exchange is set up by root (it gives each student a "
                         "folder they own): run it with sudo")
    try:
        staff = grp.getgrnam(instructors)
    except KeyError:
        raise ValueError(f"no Unix group {instructors!r}: make it (groupadd {instructors}) "
                         f"and add each instructor (usermod -aG {instructors} NAME)") from None
    if not _NAME.fullmatch(course_id):
        raise ValueError(f"course id {course_id!r}: use letters, digits, '_', '.', '-'")
    users = {}
    for sid in students:
        if not _NAME.fullmatch(sid):
            raise ValueError(f"student id {sid!r} is not a Unix user name (letters, digits, "
                             "'_', '.', '-'; no '+', '*' or '/'): the private exchange names "
                             "each student's folders after the user their server runs as")
        try:
            users[sid] = pwd.getpwnam(sid)
        except KeyError:
            raise ValueError(f"student {sid!r} has no Unix user on this machine: create it "
                             "(useradd, or the hub's first login) or fix the roster") from None
        if users[sid].pw_uid == 0 or sid in staff.gr_mem or users[sid].pw_gid == staff.gr_gid:
            raise ValueError(f"student {sid!r} is root or in the instructors' group "
                             f"{instructors!r}: they would read every submission. Take them "
                             f"out (gpasswd -d {sid} {instructors}) or off the roster")
    root = Path(root).absolute()
    problem = _unsafe_above(root)
    if problem:
        raise ValueError(problem)
    done = SetUp([], [])
    course = root / course_id
    root.parent.mkdir(parents=True, exist_ok=True)
    fresh = not root.exists()
    _folder(root, 0, 0, MODES["root"][2], done, shared_is_refused=not fresh)
    _folder(course, 0, 0, MODES["course"][2], done)
    for name in (OUTBOUND, INBOUND, FEEDBACK):
        _folder(course / name, 0, staff.gr_gid, MODES[name][2], done)
    for sid, user in users.items():
        _folder(course / INBOUND / sid, user.pw_uid, staff.gr_gid,
                MODES[f"{INBOUND}/SID"][2], done)
        _folder(course / FEEDBACK / sid, user.pw_uid, staff.gr_gid,
                MODES[f"{FEEDBACK}/SID"][2], done)
    for name in (INBOUND, FEEDBACK):
        extra = sorted(set(os.listdir(course / name)) - set(users))
        if extra:
            done.warnings.append(f"{course / name} also holds {extra} (not on this roster): "
                                 "left as they are")
    try:
        hardlinks = Path("/proc/sys/fs/protected_hardlinks").read_text().strip()
    except OSError:
        hardlinks = "1"
    if hardlinks != "1":
        done.warnings.append("fs.protected_hardlinks is off: a student could hard-link a file "
                             "they cannot read into their submission for an instructor to "
                             "copy; turn it on (sysctl -w fs.protected_hardlinks=1)")
    return done


def _unsafe_above(root: Path) -> str | None:
    """Why a folder above ``root`` lets someone other than root replace what is below it."""
    for parent in reversed(root.parents):
        try:
            info = os.lstat(parent)
        except FileNotFoundError:
            continue
        if stat.S_ISLNK(info.st_mode):
            parent = Path(os.path.realpath(parent))
            info = os.stat(parent)
        if info.st_uid != 0 or (info.st_mode & 0o022 and not info.st_mode & stat.S_ISVTX):
            return (f"{parent}, above the exchange {root}, can be changed by a user other "
                    "than root: put the exchange under root-owned folders (/srv/nbgrader/...)")
    return None


def _folder(path: Path, uid: int, gid: int, mode: int, done: SetUp,
            shared_is_refused: bool = False) -> None:
    """``path`` made or corrected to ``uid:gid mode`` (never through a link).
    ``shared_is_refused``: a folder others could write before is refused, not corrected
    (nbgrader's default exchange root: who knows what its users left in it)."""
    try:
        os.mkdir(path, 0o700)
        done.changed.append(f"made {path}")
    except FileExistsError:
        pass
    try:
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError as exc:
        raise ValueError(f"{path} is not a plain folder ({exc.strerror}): move it aside and "
                         "run the set-up again") from None
    try:
        info = os.fstat(fd)
        if shared_is_refused and (info.st_uid != 0 or info.st_mode & 0o022):
            raise ValueError(f"{path} exists and others than root could change it (owner uid "
                             f"{info.st_uid}, mode {info.st_mode & 0o7777:o}; nbgrader's "
                             "default exchange is 0777): set up the private exchange at a "
                             "new path, or move this one aside first")
        if (info.st_uid, info.st_gid, info.st_mode & 0o7777) != (uid, gid, mode):
            os.fchown(fd, uid, gid)
            os.fchmod(fd, mode)   # after fchown, which clears the setgid bit
            done.changed.append(f"{path}: owner {uid}:{gid}, mode {mode:o}")
    finally:
        os.close(fd)


def config_block(root, course_id: str = "cobotlab") -> str:
    """The ``nbgrader_config.py`` lines that use the private exchange at ``root`` (for
    every user of the machine: /etc/jupyter/nbgrader_config.py)."""
    lines = [_BEGIN,
             "# cobotlab's private exchange (autograder.exchange; docs/exchange.md)",
             f"c.Exchange.root = {str(Path(root).absolute())!r}",
             f"c.CourseDirectory.course_id = {course_id!r}"]
    lines += [f'c.ExchangeFactory.{key} = "autograder.exchange.{name}"'
              for key, name in _CLASSES.items()]
    return "\n".join([*lines, _END, ""])


def write_config(path, root, course_id: str = "cobotlab") -> Path:
    """Put :func:`config_block` into the config file ``path`` (made if missing, a block
    written before replaced, every other line kept)."""
    path = Path(path)
    text = path.read_text() if path.exists() else "c = get_config()  # noqa: F821\n"
    if _BEGIN in text and _END in text:
        head, rest = text.split(_BEGIN, 1)
        text = head + rest.split(_END, 1)[1].lstrip("\n")
    if "get_config()" not in text:
        text = "c = get_config()  # noqa: F821\n" + text
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text.rstrip("\n") + "\n" + config_block(root, course_id))
    os.chmod(path, 0o644)
    return path


def layout_problem(root, course_id: str = "") -> str | None:
    """Why ``root`` (and ``root/course_id``) is not a private exchange :func:`set_up` made,
    or None."""
    root = Path(root)
    for path, wanted in ((root, "root"), (root / course_id, "course")):
        if wanted == "course" and not course_id:
            break
        try:
            info = os.lstat(path)
        except OSError:
            return (f"{path} does not exist: the private exchange is set up by root "
                    f"({_SETUP}; docs/exchange.md)")
        if not stat.S_ISDIR(info.st_mode) or info.st_uid != 0 or info.st_mode & 0o022:
            return (f"{path} is not a root-owned folder only root may change (mode "
                    f"{info.st_mode & 0o7777:o}, owner uid {info.st_uid}): not a private "
                    f"exchange; an admin sets it up with `{_SETUP}` (docs/exchange.md)")
    return None


def _me() -> str:
    """The Unix user this process runs as: the only student it may act for."""
    return pwd.getpwuid(os.getuid()).pw_name


# ------------------------------------------------------------------------ nbgrader's classes


class _Private:
    """What every operation shares: the layout is checked instead of nbgrader's "the root
    must be world-writable" (which release_assignment would even chmod)."""

    def ensure_root(self):
        problem = layout_problem(self.root, self.coursedir.course_id if self.coursedir else "")
        if problem:
            self.fail(problem)

    def start(self):
        self.ensure_root()   # also with groupshared, where nbgrader skips it
        return super().start()

    def _student(self) -> str:
        """This user's own id; a student id given on the command line must be the same."""
        me, claimed = _me(), (self.coursedir.student_id or "*")
        if claimed not in ("*", me):
            self.fail(f"the private exchange acts for your own Unix user ({me}) only, not "
                      f"for {claimed!r}")
        return me

    def _course_folder(self, name: str) -> str:
        if not self.coursedir.course_id:
            self.fail("No course id specified. Re-run with --course flag.")
        return os.path.join(self.root, self.coursedir.course_id, name)

    def _not_yours(self, path: str) -> None:
        self.fail(f"{path} is not there or not yours: the admin gives each student on the "
                  f"roster their folders ({_SETUP}); a student added since needs the set-up "
                  "run again")


class PrivateExchange(_Private, default.Exchange):
    """The exchange itself (``c.ExchangeFactory.exchange``)."""


class PrivateFetchAssignment(_Private, default.ExchangeFetchAssignment):
    """``nbgrader fetch_assignment``: outbound/ is readable by everyone, as nbgrader's."""


class PrivateReleaseAssignment(_Private, default.ExchangeReleaseAssignment):
    """``nbgrader release_assignment`` by a member of the instructors' group."""

    def init_dest(self):
        self.course_path = os.path.join(self.root, self.coursedir.course_id)
        self.outbound_path = self._course_folder(OUTBOUND)
        self.inbound_path = self._course_folder(INBOUND)
        self.dest_path = os.path.join(self.outbound_path, self.coursedir.assignment_id)
        if not os.access(self.outbound_path, os.W_OK | os.X_OK):
            self.fail(f"you ({_me()}) cannot write {self.outbound_path}: release as a member "
                      "of the instructors' group (`id` lists yours; a new member logs in "
                      "again)")

    def set_perms(self, dest, fileperms, dirperms):
        # every instructor may replace a release (--force), not only the one who made it
        super().set_perms(dest, _RELEASED_FILE, _RELEASED_DIR)


class PrivateSubmit(_Private, default.ExchangeSubmit):
    """``nbgrader submit``: into inbound/<your user>/, readable by the instructors only."""

    def init_dest(self):
        if not self.authenticator.has_access(self.coursedir.student_id,
                                             self.coursedir.course_id):
            self.fail("You do not have access to this course.")
        sid = self._student()
        self.inbound_path = os.path.join(self._course_folder(INBOUND), sid)
        if not os.access(self.inbound_path, os.W_OK | os.X_OK):
            self._not_yours(self.inbound_path)
        self.cache_path = os.path.join(self.cache, self.coursedir.course_id)
        random_str = secrets.token_urlsafe(9)
        self.assignment_filename = \
            f"{sid}+{self.coursedir.assignment_id}+{self.timestamp}+{random_str}"

    def copy_files(self):
        self.init_release()
        submission_secret = secrets.token_hex(64)
        dest_path = os.path.join(self.inbound_path, self.assignment_filename)
        cache_path = os.path.join(self.cache_path, self.assignment_filename.rsplit("+", 1)[0])
        self.log.info("Source: %s", self.src_path)
        self.log.info("Destination: %s", dest_path)
        self.check_filename_diff()
        exchange_files = {"timestamp.txt": self.timestamp,
                          "submission_secret.txt": submission_secret}
        # Made here, so it takes the instructors' group from inbound/<you>/ (setgid). Its
        # files are made before the copy, whose last step (copystat) drops the setgid bit
        # (only a member of the group may set it): a file made after would be yours alone.
        os.mkdir(dest_path, _SUBMITTED_DIR)
        _write_texts(dest_path, exchange_files)
        self._copy_into(self.src_path, dest_path)
        _write_texts(dest_path, exchange_files)   # a student's own file of that name: ours
        self.set_perms(dest_path, _SUBMITTED_FILE, _SUBMITTED_DIR)
        self.do_copy(self.src_path, cache_path)
        _write_texts(cache_path, exchange_files)
        self.log.info("Submitted as: %s %s %s", self.coursedir.course_id,
                      self.coursedir.assignment_id, self.timestamp)

    def _copy_into(self, src, dest):
        """nbgrader's copy of the assignment (its size cap, ignore and include globs, file
        size cap) into the existing folder ``dest``."""
        size, cap = self.get_size(src), 1000 * self.coursedir.max_dir_size
        if size > cap:
            self.fail(f"Directory size is too big. Size is {size}, maximum size is {cap}")
        shutil.copytree(src, dest, dirs_exist_ok=True, ignore=ignore_patterns(
            exclude=self.coursedir.ignore, include=self.coursedir.include,
            max_file_size=self.coursedir.max_file_size, log=self.log))


def _write_texts(folder: str, texts: dict[str, str]) -> None:
    for name, text in texts.items():
        with open(os.path.join(folder, name), "w") as fh:
            fh.write(text)


class _Globs:
    """``name in _Globs(patterns)``: the name matches one of nbgrader's ignore globs."""

    def __init__(self, patterns):
        self.patterns = list(patterns or [])

    def __contains__(self, name) -> bool:
        from fnmatch import fnmatch
        return any(fnmatch(name, p) for p in self.patterns)


class PrivateCollect(_Private, default.ExchangeCollect):
    """``nbgrader collect`` by a member of the instructors' group: each student's latest
    submission from their own folder, copied as data (regular files and folders, never a
    link, a pipe or a device), so a student's folder cannot hand over anything else."""

    def init_src(self):
        # Instructors' side only (never in a student's server): the one gradebook reader.
        import autograder.gradebook as gradebook

        self.inbound_path = self._course_folder(INBOUND)
        if not os.access(self.inbound_path, os.R_OK | os.X_OK):
            self.fail(f"you ({_me()}) cannot list {self.inbound_path}: collect as a member of "
                      "the instructors' group (`id` lists yours; a new member logs in again)")
        wanted, assignment = self.coursedir.student_id or "*", self.coursedir.assignment_id
        latest: dict[str, list[dict]] = {}
        for path in sorted(glob.glob(os.path.join(self.inbound_path, wanted,
                                                  f"{wanted}+{assignment}+*"))):
            owner_dir, name = os.path.split(path)
            sid = os.path.basename(owner_dir)
            try:
                record = self._path_to_record(path)
                info = os.lstat(path)
                uid = pwd.getpwnam(sid).pw_uid
            except Exception as exc:  # noqa: BLE001 - one odd name must not stop the class
                self.log.warning("not collected: %s (%s)", path, exc)
                continue
            if record["username"] != sid or not stat.S_ISDIR(info.st_mode) or \
                    info.st_uid != uid:
                self.log.warning("not collected: %s (in %s's folder, but named for %s, or not "
                                 "a folder %s owns)", path, sid, record["username"], sid)
                continue
            record["filename"] = os.path.join(sid, name)
            # The name's time is the student's own clock, or their choice; the folder's
            # change time is the kernel's, and can only move later (chmod, rename).
            changed = datetime.fromtimestamp(info.st_ctime, timezone.utc)
            stamped = record["timestamp"]
            if stamped.tzinfo is None:
                stamped = stamped.replace(tzinfo=timezone.utc)
            if stamped < changed - _CLOCK_SLACK:
                self.log.warning("%s: its name says %s, but the folder was made or changed "
                                 "at %s: a forged time? (a late submission named as on time)",
                                 path, stamped, changed.isoformat(sep=" "))
            latest.setdefault(sid, []).append(record)
        self.duedate = gradebook.duedate(Path(self.coursedir.root), assignment)
        self.src_records = []
        for records in latest.values():
            records = self._sort_by_timestamp(records)
            if self.before_duedate and self.duedate is not None:
                on_time = [r for r in records if r["timestamp"] <= self.duedate]
                records = on_time or records
            self.src_records.append(records[0])

    def do_copy(self, src, dest):
        caps = TreeCaps(file_bytes=self.coursedir.max_file_size * 1000,
                        total_bytes=self.coursedir.max_dir_size * 1000, files=10_000, depth=32)
        os.makedirs(dest)
        try:
            with open_folder(os.path.dirname(src), [os.path.basename(src)]) as folder:
                skipped = copy_tree(folder, Path(dest), caps,
                                    ignore=_Globs(self.coursedir.ignore))
        except Refused as exc:   # the student's own doing: the others are still collected
            shutil.rmtree(dest)
            self.log.error("not collected: %s (%s)", src, exc)
            return
        for s in skipped:
            self.log.warning("not collected from %s: %s (%s)", src, s.path, s.detail)


class PrivateReleaseFeedback(_Private, default.ExchangeReleaseFeedback):
    """``nbgrader release_feedback`` into each student's feedback/<student>/, written so
    that nothing a student put there (a link, say) is followed."""

    def init_dest(self):
        self.dest_path = self.outbound_feedback_path = self._course_folder(FEEDBACK)
        if not os.access(self.dest_path, os.X_OK):
            self.fail(f"you ({_me()}) cannot enter {self.dest_path}: release as a member of "
                      "the instructors' group")

    def copy_files(self):
        exclude = set(filter(None, (self.coursedir.student_id_exclude or "").split(",")))
        pattern = re.escape(os.path.sep).join([
            self.coursedir.format_path(self.coursedir.feedback_directory, "(?P<student_id>.*)",
                                       self.coursedir.assignment_id, escape=True),
            "(?P<notebook_id>.*).html"])
        failed = []
        for html_file in sorted(glob.glob(os.path.join(self.src_path, "*.html"))):
            match = re.match(pattern, html_file)
            if match is None:
                self.log.error("Could not match %r with %r", html_file, pattern)
                continue
            sid, notebook_id = match.group("student_id"), match.group("notebook_id")
            if sid in exclude:
                continue
            try:
                secret_path = os.path.join(os.path.dirname(html_file), "submission_secret.txt")
                with open(secret_path) as fh:
                    name = notebook_hash(secret=fh.read(), notebook_id=notebook_id) + ".html"
                with open(html_file, "rb") as fh:
                    page = fh.read()
                _replace(self.dest_path, sid, name, page)
            except (Refused, OSError) as exc:   # the others' feedback is still released
                failed.append(f"{sid} ({exc})")
                continue
            self.log.info("Released feedback for %s on %s/%s", sid,
                          self.coursedir.assignment_id, notebook_id)
        if failed:
            self.fail(f"feedback not released for {', '.join(failed)}: releasing needs the "
                      "instructors' group, each page its submission_secret.txt (from "
                      f"collect), and each student a feedback folder of their own ({_SETUP})")


def _replace(feedback_root: str, sid: str, name: str, data: bytes) -> None:
    """Write ``feedback_root/sid/name`` as a new file renamed into place: a link or file
    the student left under that name is replaced, never followed or written through."""
    with open_folder(feedback_root, [sid]) as folder:
        temporary = f".{name}.{secrets.token_hex(8)}.tmp"
        fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW
                     | os.O_CLOEXEC, _FEEDBACK_FILE, dir_fd=folder.fd)
        try:
            with os.fdopen(fd, "wb") as f:
                os.fchmod(f.fileno(), _FEEDBACK_FILE)   # whatever the umask
                f.write(data)
            os.rename(temporary, name, src_dir_fd=folder.fd, dst_dir_fd=folder.fd)
        except BaseException:
            try:
                os.unlink(temporary, dir_fd=folder.fd)
            except OSError:
                pass
            raise


class PrivateFetchFeedback(_Private, default.ExchangeFetchFeedback):
    """``nbgrader fetch_feedback``: from feedback/<your user>/, for the submissions in your
    own cache (each page is named after its submission's secret)."""

    def init_src(self):
        sid = self._student()
        self.src_path = self.outbound_path = os.path.join(self._course_folder(FEEDBACK), sid)
        if not os.access(self.src_path, os.R_OK | os.X_OK):
            self._not_yours(self.src_path)
        self.cache_path = os.path.join(self.cache, self.coursedir.course_id)
        assignment = self.coursedir.assignment_id or "*"
        self.feedback_files = []
        for submission in sorted(glob.glob(os.path.join(self.cache_path,
                                                        f"*+{assignment}+*"))):
            parts = os.path.basename(submission).split("+")
            secret_path = os.path.join(submission, "submission_secret.txt")
            if len(parts) != 3 or not os.path.isfile(secret_path):
                continue
            with open(secret_path) as fh:
                secret = fh.read()
            for notebook in sorted(glob.glob(os.path.join(submission, "*.ipynb"))):
                notebook_id = os.path.splitext(os.path.basename(notebook))[0]
                page = os.path.join(self.src_path, notebook_hash(
                    secret=secret, notebook_id=notebook_id) + ".html")
                if os.path.isfile(page):
                    self.feedback_files.append((notebook_id, parts[2], page))
                    self.log.info("Found feedback for '%s/%s' submitted at %s",
                                  parts[1], notebook_id, parts[2])
                else:
                    self.log.warning("No feedback yet for '%s/%s' submitted at %s",
                                     parts[1], notebook_id, parts[2])


class PrivateList(_Private, default.ExchangeList):
    """``nbgrader list`` (and the Assignments tab's lists): ``--inbound`` shows a student
    their own submissions only (an instructor every student's); feedback is looked for in
    the student's own folder."""

    def init_dest(self):
        if not self.inbound:
            return super().init_dest()
        course = self.coursedir.course_id or "*"
        assignment = self.coursedir.assignment_id or "*"
        student = self.coursedir.student_id or "*"
        pattern = os.path.join(self.root, course, INBOUND, "*", f"{student}+{assignment}+*")
        mine = os.path.join(self.root, course, INBOUND, _me(), f"{_me()}+{assignment}+*")
        # instructors list inbound/*; a student passes through it to their own folder only
        self.assignments = sorted(set(glob.glob(pattern)) | set(glob.glob(mine)))
        if student != "*":
            self.assignments = [a for a in self.assignments
                                if os.path.basename(a).startswith(student + "+")]

    def parse_assignment(self, assignment):
        if not self.inbound:
            return super().parse_assignment(assignment)
        match = re.match(r".*/(?P<course_id>[^/]*)/inbound/[^/]*/(?P<student_id>[^+/]*)\+"
                         r"(?P<assignment_id>[^+/]*)\+(?P<timestamp>[^+/]*)"
                         r"(?P<random_string>\+[^/]*)?$", assignment)
        if match is None:
            raise RuntimeError(f"Could not parse {assignment!r} as a submission")
        return match.groupdict()

    def parse_assignments(self):
        assignments = super().parse_assignments()
        if self.inbound or self.cached:
            for assignment in assignments:
                for info in assignment["submissions"]:
                    self._feedback_state(info)
        return assignments

    def _feedback_state(self, info: dict) -> None:
        """nbgrader looked for released feedback in feedback/; here it is in
        feedback/<student>/."""
        secret_path = os.path.join(info["path"], "submission_secret.txt")
        if not os.path.isfile(secret_path) or not info["notebooks"]:
            return
        with open(secret_path) as fh:
            secret = fh.read()
        for nb in info["notebooks"]:
            page = os.path.join(self.root, info["course_id"], FEEDBACK, info["student_id"],
                                notebook_hash(secret=secret, notebook_id=nb["notebook_id"])
                                + ".html")
            nb["has_exchange_feedback"] = os.path.isfile(page)
            local = nb.get("local_feedback_path")
            nb["feedback_updated"] = bool(
                nb["has_exchange_feedback"] and nb["has_local_feedback"] and local
                and _same_bytes(page, local) is False)
        info["has_exchange_feedback"] = all(nb["has_exchange_feedback"]
                                            for nb in info["notebooks"])
        info["feedback_updated"] = any(nb["feedback_updated"] for nb in info["notebooks"])


def _same_bytes(a: str, b: str) -> bool:
    with open(a, "rb") as fa, open(b, "rb") as fb:
        return fa.read() == fb.read()
