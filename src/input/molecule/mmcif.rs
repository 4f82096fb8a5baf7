//! mmCIF: the `_atom_site` category (a loop, or one atom as tag-value pairs) read as
//! atoms, with the rules of the PDB reader.
//!
//! The lexer follows CIF 1.1 as mmCIF uses it: whitespace-separated words; `#` starts a
//! comment; `'...'` and `"..."` strings end at a quote followed by whitespace (so
//! `"O5'"` is `O5'`) and may not span lines; a `;` in the first column of a line opens
//! a text field that the next line starting with `;` closes; `?` (unknown) and `.`
//! (inapplicable) are values only when unquoted; `loop_`, `data_...`, `save_...`,
//! `global_` and `stop_` are reserved. Tags are matched without regard to case.
//!
//! Columns read: `Cartn_x`, `Cartn_y`, `Cartn_z` (required; a value that is not a
//! finite number is refused with its line), `group_PDB` (ATOM or HETATM; ATOM when
//! absent), `pdbx_PDB_model_num` (the first model met unless `model`), `label_alt_id`
//! (the first alternate location met for each atom), `type_symbol` (the element; when
//! it is unknown, `?`, `.` or `X`, the element comes from the atom name), `label_atom_id`
//! (else `auth_atom_id`), `label_comp_id` (else `auth_comp_id`), `auth_asym_id` (else
//! `label_asym_id`), `auth_seq_id` (else `label_seq_id`) and `pdbx_PDB_ins_code`. Other
//! columns (occupancy, `B_iso_or_equiv`, ...) are not looked at, so values such as `inf`
//! there do not matter. Waters are left out whether ATOM or HETATM, and other HETATM
//! groups unless `keep_hetatm`, as for PDB. Rows are read as they stream by and reading
//! stops at the end of the first `_atom_site` category.
//!
//! A small reader rather than the `pdbtbx` crate (0.12): pdbtbx names a loop row rather
//! than the file's line in its errors, panics on `?` in `type_symbol` or a coordinate,
//! refuses a file whose `B_iso_or_equiv` holds `inf`, and has no element fallback.

use std::collections::{BTreeMap, BTreeSet, HashSet};

use super::rules::{
    capitalize, element_from_name, keep_hetero, note_missing, table_radius, Reader, WATERS,
};
use super::{Atom, Molecule, MoleculeOptions};
use crate::input::InputError;

/// What a token is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// `_category.item`.
    Tag,
    /// `loop_`.
    Loop,
    /// `data_NAME`.
    Data,
    /// `save_`, `global_`, `stop_`: frames and words harmap has no use for.
    Reserved,
    /// An unquoted value (`?` and `.` are the unknown and inapplicable values).
    Bare,
    /// A quoted string or a text field: always a literal value.
    Quoted,
}

/// A word of the file: its text (without quotes) and the line it starts on.
#[derive(Clone, Copy, Debug)]
struct Token<'a> {
    kind: Kind,
    text: &'a str,
    line: usize,
}

impl<'a> Token<'a> {
    fn is_value(&self) -> bool {
        matches!(self.kind, Kind::Bare | Kind::Quoted)
    }

    /// The value, or `None` for the unquoted `?` and `.`.
    fn value(&self) -> Option<&'a str> {
        match (self.kind, self.text) {
            (Kind::Bare, "?" | ".") => None,
            _ => Some(self.text),
        }
    }
}

/// CIF 1.1 tokens of a text, with their lines.
struct Lexer<'a, 'r> {
    s: &'a str,
    pos: usize,
    line: usize,
    r: &'r Reader<'r>,
}

fn blank(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | b'\n')
}

impl<'a> Lexer<'a, '_> {
    fn next_token(&mut self) -> Result<Option<Token<'a>>, InputError> {
        let b = self.s.as_bytes();
        loop {
            while self.pos < b.len() && blank(b[self.pos]) {
                if b[self.pos] == b'\n' {
                    self.line += 1;
                }
                self.pos += 1;
            }
            if self.pos >= b.len() {
                return Ok(None);
            }
            if b[self.pos] == b'#' {
                while self.pos < b.len() && b[self.pos] != b'\n' {
                    self.pos += 1;
                }
                continue;
            }
            break;
        }
        let start = self.pos;
        let line = self.line;
        let first = b[start];
        if first == b';' && (start == 0 || b[start - 1] == b'\n') {
            // The field runs to the next line that starts with `;`.
            let Some(end) = self.s[start..].find("\n;").map(|k| start + k) else {
                return Err(self.r.err(
                    line,
                    "a text field opens here (a line starting with `;`) and no later line starting with `;` closes it",
                ));
            };
            let text = self.s[start + 1..end].trim_end_matches('\r');
            self.line += self.s[start..=end].matches('\n').count();
            self.pos = end + 2;
            return Ok(Some(Token {
                kind: Kind::Quoted,
                text,
                line,
            }));
        }
        if first == b'\'' || first == b'"' {
            // Closed by the same quote followed by a blank or the end of the text.
            let mut k = start + 1;
            loop {
                if k >= b.len() || b[k] == b'\n' {
                    return Err(self.r.err(
                        line,
                        format!(
                            "a string opened with {} is not closed on its line",
                            first as char
                        ),
                    ));
                }
                if b[k] == first && (k + 1 >= b.len() || blank(b[k + 1])) {
                    break;
                }
                k += 1;
            }
            self.pos = k + 1;
            return Ok(Some(Token {
                kind: Kind::Quoted,
                text: &self.s[start + 1..k],
                line,
            }));
        }
        let mut k = start;
        while k < b.len() && !blank(b[k]) {
            k += 1;
        }
        self.pos = k;
        let text = &self.s[start..k];
        let lower = |p: &str| {
            text.get(..p.len())
                .is_some_and(|h| h.eq_ignore_ascii_case(p))
        };
        let kind = if first == b'_' {
            Kind::Tag
        } else if text.eq_ignore_ascii_case("loop_") {
            Kind::Loop
        } else if lower("data_") {
            Kind::Data
        } else if lower("save_")
            || text.eq_ignore_ascii_case("global_")
            || text.eq_ignore_ascii_case("stop_")
        {
            Kind::Reserved
        } else {
            Kind::Bare
        };
        Ok(Some(Token { kind, text, line }))
    }
}

/// The `_atom_site` items harmap reads, as lower-case names after `_atom_site.`.
const ITEMS: [&str; 16] = [
    "cartn_x",
    "cartn_y",
    "cartn_z",
    "group_pdb",
    "pdbx_pdb_model_num",
    "label_alt_id",
    "type_symbol",
    "label_atom_id",
    "auth_atom_id",
    "label_comp_id",
    "auth_comp_id",
    "auth_asym_id",
    "label_asym_id",
    "auth_seq_id",
    "label_seq_id",
    "pdbx_pdb_ins_code",
];

/// Where each of [`ITEMS`] is in a row, if present.
struct Columns([Option<usize>; ITEMS.len()]);

impl Columns {
    /// From the tags of the category (`_atom_site.Cartn_x`, ...), in row order.
    fn new(tags: &[&str]) -> Self {
        let mut c = [None; ITEMS.len()];
        for (i, tag) in tags.iter().enumerate() {
            let item = tag["_atom_site.".len()..].to_ascii_lowercase();
            if let Some(k) = ITEMS.iter().position(|&n| n == item) {
                c[k].get_or_insert(i);
            }
        }
        Self(c)
    }

    /// The place of `item` in a row.
    fn index(&self, item: &str) -> Option<usize> {
        let k = ITEMS.iter().position(|&n| n == item)?;
        self.0[k]
    }

    fn token<'t, 'a>(&self, row: &'t [Token<'a>], item: &str) -> Option<&'t Token<'a>> {
        self.index(item).map(|i| &row[i])
    }

    /// The value of `item` in `row`, `None` when the column is absent or holds `?` or `.`.
    fn get<'a>(&self, row: &[Token<'a>], item: &str) -> Option<&'a str> {
        self.token(row, item).and_then(Token::value)
    }

    /// The first of `items` that has a value.
    fn first<'a>(&self, row: &[Token<'a>], items: &[&str]) -> Option<&'a str> {
        items.iter().find_map(|i| self.get(row, i))
    }
}

fn is_atom_site(tag: &str) -> bool {
    const P: &str = "_atom_site.";
    tag.len() > P.len()
        && tag
            .get(..P.len())
            .is_some_and(|h| h.eq_ignore_ascii_case(P))
}

/// Find the first `_atom_site` category of `text` and hand its rows, one by one, to
/// `sink`: a loop is never held whole, so files of millions of atoms need memory for
/// the atoms kept only.
fn atom_site<'a>(
    r: &Reader<'_>,
    text: &'a str,
    sink: &mut Atoms<'a, '_>,
) -> Result<(), InputError> {
    let mut lx = Lexer {
        s: text,
        pos: 0,
        line: 1,
        r,
    };
    // An `_atom_site` written as tag-value pairs (a single atom): tags, values, line.
    let mut pairs: Option<(Vec<&'a str>, Vec<Token<'a>>, usize)> = None;
    let mut pending: Option<Token<'a>> = None;
    while let Some(t) = match pending.take() {
        Some(t) => Some(t),
        None => lx.next_token()?,
    } {
        match t.kind {
            Kind::Loop => {
                let mut tags = Vec::new();
                let mut next = lx.next_token()?;
                while let Some(tag) = next.filter(|n| n.kind == Kind::Tag) {
                    tags.push(tag.text);
                    next = lx.next_token()?;
                }
                if !tags.first().is_some_and(|t| is_atom_site(t)) {
                    // Another category's loop: step over its values.
                    while next.is_some_and(|v| v.is_value()) {
                        next = lx.next_token()?;
                    }
                    pending = next;
                    continue;
                }
                if let Some(bad) = tags.iter().find(|t| !is_atom_site(t)) {
                    return Err(r.err(
                        t.line,
                        format!("the _atom_site loop also lists `{bad}`, of another category"),
                    ));
                }
                sink.header(&tags, t.line)?;
                let mut row = Vec::with_capacity(tags.len());
                while let Some(v) = next.filter(Token::is_value) {
                    row.push(v);
                    if row.len() == tags.len() {
                        sink.row(&row)?;
                        row.clear();
                    }
                    next = lx.next_token()?;
                }
                if let Some(last) = row.last() {
                    return Err(r.err(
                        last.line,
                        format!(
                            "the _atom_site loop ends inside a row: {} value(s) of {} (truncated file, or a value with a blank in it that lacks quotes?)",
                            row.len(),
                            tags.len()
                        ),
                    ));
                }
                return Ok(());
            }
            Kind::Tag => {
                let v = lx.next_token()?;
                let Some(v) = v.filter(Token::is_value) else {
                    if is_atom_site(t.text) {
                        return Err(r.err(t.line, format!("`{}` has no value", t.text)));
                    }
                    pending = v;
                    continue;
                };
                if is_atom_site(t.text) {
                    let p = pairs.get_or_insert_with(|| (Vec::new(), Vec::new(), t.line));
                    p.0.push(t.text);
                    p.1.push(v);
                } else if pairs.is_some() {
                    break;
                }
            }
            Kind::Data if pairs.is_some() => break,
            Kind::Data | Kind::Reserved | Kind::Bare | Kind::Quoted => {}
        }
    }
    if let Some((tags, values, line)) = pairs {
        sink.header(&tags, line)?;
        sink.row(&values)?;
    }
    Ok(())
}

/// A number with an optional standard uncertainty in parentheses (`12.345(6)`).
fn strip_uncertainty(s: &str) -> &str {
    match s.strip_suffix(')').and_then(|h| h.rsplit_once('(')) {
        Some((v, su))
            if !v.is_empty() && !su.is_empty() && su.bytes().all(|b| b.is_ascii_digit()) =>
        {
            v
        }
        _ => s,
    }
}

/// The molecule being read from the rows of `_atom_site`.
struct Atoms<'a, 'r> {
    r: &'r Reader<'r>,
    o: &'r MoleculeOptions,
    m: Molecule,
    cols: Columns,
    /// Where Cartn_x, Cartn_y and Cartn_z are in a row.
    coord: [usize; 3],
    missing: BTreeMap<String, usize>,
    models: BTreeSet<u32>,
    first_model: Option<u32>,
    /// Atoms met with an alternate location: (chain, number, insertion code, residue,
    /// name).
    seen: HashSet<(&'a str, i32, &'a str, &'a str, &'a str)>,
}

impl<'a> Atoms<'a, '_> {
    /// The category's tags, in row order, and the line where they start.
    fn header(&mut self, tags: &[&str], line: usize) -> Result<(), InputError> {
        self.cols = Columns::new(tags);
        for (k, axis) in ["x", "y", "z"].iter().enumerate() {
            self.coord[k] = self.cols.index(&format!("cartn_{axis}")).ok_or_else(|| {
                self.r.err(
                    line,
                    format!("the _atom_site category has no _atom_site.Cartn_{axis} column; harmap reads Cartesian coordinates"),
                )
            })?;
        }
        Ok(())
    }

    /// One row: an atom, kept or left out by the PDB reader's rules.
    fn row(&mut self, row: &[Token<'a>]) -> Result<(), InputError> {
        let (r, o, cols) = (self.r, self.o, &self.cols);
        let line = row[0].line;
        let model = match cols.token(row, "pdbx_pdb_model_num") {
            Some(t) => match t.value() {
                None => 1,
                Some(v) => v.parse::<u32>().map_err(|_| {
                    r.err(
                        t.line,
                        format!("pdbx_PDB_model_num is `{v}`, not a model number"),
                    )
                })?,
            },
            None => 1,
        };
        self.models.insert(model);
        let first = *self.first_model.get_or_insert(model);
        if o.model.unwrap_or(first) != model {
            return Ok(());
        }
        let het = match cols.get(row, "group_pdb") {
            None => false,
            Some(g) if g.eq_ignore_ascii_case("ATOM") => false,
            Some(g) if g.eq_ignore_ascii_case("HETATM") => true,
            Some(g) => {
                let line = cols.token(row, "group_pdb").map_or(line, |t| t.line);
                return Err(r.err(line, format!("group_PDB is `{g}`; ATOM or HETATM expected")));
            }
        };
        let mut xyz = [0.0; 3];
        for (k, axis) in ["x", "y", "z"].iter().enumerate() {
            let t = &row[self.coord[k]];
            xyz[k] = r.number(
                t.line,
                &format!("{axis} (_atom_site.Cartn_{axis})"),
                strip_uncertainty(t.text),
            )?;
        }
        let name = cols
            .first(row, &["label_atom_id", "auth_atom_id"])
            .unwrap_or("");
        let res = cols
            .first(row, &["label_comp_id", "auth_comp_id"])
            .unwrap_or("");
        let chain = cols
            .first(row, &["auth_asym_id", "label_asym_id"])
            .unwrap_or("");
        let seq = cols
            .first(row, &["auth_seq_id", "label_seq_id"])
            .and_then(|s| s.parse::<i32>().ok())
            .unwrap_or(0);
        if cols.get(row, "label_alt_id").is_some() {
            let ins = cols.get(row, "pdbx_pdb_ins_code").unwrap_or("");
            if !self.seen.insert((chain, seq, ins, res, name)) {
                return Ok(());
            }
        }
        if (het || WATERS.contains(&res)) && !keep_hetero(&mut self.m, res, o) {
            return Ok(());
        }
        let symbol: String = cols
            .get(row, "type_symbol")
            .unwrap_or("")
            .chars()
            .take_while(char::is_ascii_alphabetic)
            .collect();
        let element = if symbol.is_empty() || symbol.eq_ignore_ascii_case("X") {
            // PDB alignment: two-letter elements start one column earlier. In mmCIF
            // an ion's atom is named as its residue (CA in CA is calcium).
            let padded = if het && name.eq_ignore_ascii_case(res) {
                format!("{name:<4}")
            } else {
                format!(" {name:<3}")
            };
            element_from_name(&padded, het)
        } else {
            capitalize(&symbol)
        };
        let radius = table_radius(&element, &mut self.missing);
        self.m.atoms.push(Atom {
            pos: glam::DVec3::from_array(xyz),
            radius,
            element,
            residue: res.to_owned(),
            chain: chain.to_owned(),
            seq,
            line,
        });
        Ok(())
    }
}

/// Read the atoms of an mmCIF text.
pub(super) fn read(
    r: &Reader<'_>,
    text: &str,
    o: &MoleculeOptions,
) -> Result<Molecule, InputError> {
    let mut a = Atoms {
        r,
        o,
        m: Molecule {
            format: "mmcif",
            ..Molecule::default()
        },
        cols: Columns::new(&[]),
        coord: [0; 3],
        missing: BTreeMap::new(),
        models: BTreeSet::new(),
        first_model: None,
        seen: HashSet::new(),
    };
    atom_site(r, text, &mut a)?;
    let Atoms {
        mut m,
        models,
        missing,
        ..
    } = a;
    if let Some(w) = o.model {
        if m.atoms.is_empty() && !models.is_empty() && !models.contains(&w) {
            return Err(InputError::invalid(
                r.path,
                format!(
                    "--model {w}: the file has {} model(s) and none numbered {w}",
                    models.len()
                ),
            ));
        }
    } else if models.len() > 1 {
        m.warnings.push(format!(
            "{} models: read the first (--model N for another)",
            models.len()
        ));
    }
    note_missing(&mut m, &missing);
    Ok(m)
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::super::{read as read_any, Atom, Molecule, MoleculeOptions};
    use crate::input::InputError;

    fn cif(text: &str, o: &MoleculeOptions) -> Result<Molecule, InputError> {
        read_any(Path::new("t.cif"), "cif", text.as_bytes(), o)
    }

    fn err(text: &str) -> String {
        cif(text, &MoleculeOptions::default())
            .unwrap_err()
            .to_string()
    }

    const HEADER: &str = "data_test
loop_
_atom_site.group_PDB
_atom_site.id
_atom_site.type_symbol
_atom_site.label_atom_id
_atom_site.label_alt_id
_atom_site.label_comp_id
_atom_site.label_asym_id
_atom_site.label_seq_id
_atom_site.pdbx_PDB_ins_code
_atom_site.Cartn_x
_atom_site.Cartn_y
_atom_site.Cartn_z
_atom_site.occupancy
_atom_site.B_iso_or_equiv
_atom_site.auth_seq_id
_atom_site.auth_asym_id
_atom_site.pdbx_PDB_model_num
";

    /// Everything but the line, which differs between the formats.
    fn same(a: &[Atom], b: &[Atom]) {
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            let key = |t: &Atom| {
                (
                    t.pos,
                    t.radius,
                    t.element.clone(),
                    t.residue.clone(),
                    t.chain.clone(),
                    t.seq,
                )
            };
            assert_eq!(key(x), key(y), "lines {} and {}", x.line, y.line);
        }
    }

    #[test]
    fn pdb_and_mmcif_of_the_same_atoms_give_the_same_atoms() {
        let pdb = [
            "ATOM      1  N   MET A   1      27.340  24.430   2.614  1.00  9.67           N",
            "ATOM      2  CA AMET A   1      26.266  25.413   2.842  0.50 10.38           C",
            "ATOM      3  CA BMET A   1      26.300  25.400   2.800  0.50 10.38           C",
            "ATOM      4  O5'  DA B  12      20.000  21.000  22.000  1.00 10.00",
            "HETATM    5 ZN    ZN B 301      10.000  10.000  10.000  1.00  9.00",
            "HETATM    6 FE   HEM B 302      11.000  10.000  10.000  1.00  9.00          FE",
            "HETATM    7  O   HOH A 401      45.747  30.081  19.708  1.00 12.43           O",
        ]
        .join("\n");
        let text = HEADER.to_owned()
            + "ATOM 1 N N . MET X 1 ? 27.340 24.430 2.614 1.00 9.67 1 A 1
ATOM 2 C CA A MET X 1 ? 26.266 25.413 2.842 0.50 10.38 1 A 1
ATOM 3 C CA B MET X 1 ? 26.300 25.400 2.800 0.50 10.38 1 A 1
ATOM 4 ? \"O5'\" . DA Y 1 ? 20.000 21.000 22.000 1.00 10.00 12 B 1
HETATM 5 . ZN . ZN Z . ? 10.000 10.000 10.000 1.00 9.00 301 B 1
HETATM 6 FE FE . HEM Z . ? 11.000 10.000 10.000 1.00 9.00 302 B 1
HETATM 7 O O . HOH W . ? 45.747 30.081 19.708 1.00 12.43 401 A 1
";
        for keep_hetatm in [false, true] {
            let o = MoleculeOptions {
                keep_hetatm,
                ..MoleculeOptions::default()
            };
            let a = read_any(Path::new("t.pdb"), "pdb", pdb.as_bytes(), &o).unwrap();
            let b = cif(&text, &o).unwrap();
            same(&a.atoms, &b.atoms);
            assert_eq!(a.left_out, b.left_out);
            assert_eq!(a.hetero_kept, b.hetero_kept);
        }
        let b = cif(
            &text,
            &MoleculeOptions {
                keep_hetatm: true,
                ..MoleculeOptions::default()
            },
        )
        .unwrap();
        let el: Vec<&str> = b.atoms.iter().map(|a| a.element.as_str()).collect();
        assert_eq!(el, ["N", "C", "O", "Zn", "Fe"]);
        assert_eq!((b.atoms[2].chain.as_str(), b.atoms[2].seq), ("B", 12));
        assert_eq!(b.atoms[0].line, 20, "the line of the row in the file");
    }

    #[test]
    fn cif_syntax_quotes_text_fields_comments_and_other_categories() {
        let text = "# a comment\ndata_x\n_struct.title 'a loop_ _atom_site.Cartn_x in a title'\n\
_cell.length_a 10 # comment after a value\n\
loop_\n_citation.id\n_citation.title\n1\n;A text field\nloop_\n_atom_site.Cartn_x 5\n;\n\
2 \"it's quoted\"\n\
loop_\n_atom_site.label_atom_id\n_atom_site.label_comp_id\n_atom_site.Cartn_x\n\
_atom_site.Cartn_y\n_atom_site.Cartn_z\n_atom_site.B_iso_or_equiv\n\
'C A' GLY 1.0(2) 2.0 3.0 inf\nCB\nGLY\n4 5 6 nan # a row over three lines\n\
loop_\n_atom_site_anisotrop.id\n1\n";
        let m = cif(text, &MoleculeOptions::default()).unwrap();
        assert_eq!(m.atoms.len(), 2, "{:?}", m.atoms);
        assert_eq!(m.atoms[0].pos, glam::DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(m.atoms[0].element, "C");
        assert_eq!(m.atoms[1].line, 22);
        assert_eq!((m.atoms[1].chain.as_str(), m.atoms[1].seq), ("", 0));
        // One atom as tag-value pairs.
        let one = "data_one\n_atom_site.type_symbol S\n_atom_site.Cartn_x 1\n\
_atom_site.Cartn_y 2\n_atom_site.Cartn_z 3\n_cell.length_a 5\n";
        let m = cif(one, &MoleculeOptions::default()).unwrap();
        assert_eq!(m.atoms.len(), 1);
        assert!((m.atoms[0].radius - 1.8).abs() < 1e-12);
    }

    /// Odd bytes anywhere give an error or atoms, never a panic.
    #[test]
    fn odd_text_does_not_panic() {
        let row = "ATOM 1 N N . MET A 1 ? 1 2 3 1 9 1 A 1\n";
        for odd in [
            "_atom_sitéé.x 1\n",
            "data_é\n_atom_site.Cartn_x\n",
            "loop_\n_atom_site.Cartn_x\n;\n",
            "loop_\n_atom_site.Cartn_x\n_atom_site.Cartn_y\n_atom_site.Cartn_z\n1 2 3()\n",
            "loop_\n_atom_site.Cartn_x\n_atom_site.Cartn_y\n_atom_site.Cartn_z\n'1' \"2\" 3\n",
            "loop_\n_atom_site.é\n1\n",
            "loop_\nloop_\n_x.y\n'\n",
            "\"",
            ";",
            "'a'b' c",
            "loop_",
            "_atom_site.Cartn_x",
        ] {
            let _ = cif(odd, &MoleculeOptions::default());
            let _ = cif(&(HEADER.to_owned() + odd), &MoleculeOptions::default());
            let _ = cif(
                &(HEADER.to_owned() + row + odd),
                &MoleculeOptions::default(),
            );
        }
        // Quoted numbers are numbers; an uncertainty in parentheses is dropped.
        let text =
            "loop_\n_atom_site.Cartn_x\n_atom_site.Cartn_y\n_atom_site.Cartn_z\n'1' \"2\" 3.5(2)\n";
        let m = cif(text, &MoleculeOptions::default()).unwrap();
        assert_eq!(m.atoms[0].pos, glam::DVec3::new(1.0, 2.0, 3.5));
    }

    #[test]
    fn models_select_like_pdb() {
        let text = HEADER.to_owned()
            + "ATOM 1 C C . MOL A 1 ? 0 0 0 1 0 1 A 1\nATOM 1 C C . MOL A 1 ? 5 0 0 1 0 1 A 2\n";
        let m = cif(&text, &MoleculeOptions::default()).unwrap();
        assert_eq!(m.atoms.len(), 1);
        assert!(m.warnings.iter().any(|w| w.contains("2 models")));
        let o = MoleculeOptions {
            model: Some(2),
            ..MoleculeOptions::default()
        };
        assert!((cif(&text, &o).unwrap().atoms[0].pos.x - 5.0).abs() < 1e-12);
        let o = MoleculeOptions {
            model: Some(3),
            ..MoleculeOptions::default()
        };
        let e = cif(&text, &o).unwrap_err().to_string();
        assert!(e.contains("--model 3") && e.contains("2 model(s)"), "{e}");
    }

    #[test]
    fn malformed_files_are_refused_with_the_line() {
        let row = |x: &str| {
            HEADER.to_owned() + &format!("ATOM 1 N N . MET A 1 ? 1 2 3 1 9 1 A 1\nATOM 2 C CA . MET A 1 ? 1 {x} 3 1 9 1 A 1\n")
        };
        for (bad, expect) in [
            ("?", "t.cif:21: y (_atom_site.Cartn_y) is `?`, not a number"),
            (".", "t.cif:21: y (_atom_site.Cartn_y) is `.`"),
            (
                "2x.4",
                "t.cif:21: y (_atom_site.Cartn_y) is `2x.4`, not a number",
            ),
            (
                "inf",
                "t.cif:21: y (_atom_site.Cartn_y) is `inf`, not a finite number",
            ),
            ("nan", "not a finite number"),
            ("'1.0", "t.cif:21: a string opened with ' is not closed"),
        ] {
            let e = err(&row(bad));
            assert!(e.contains(expect), "{bad}: {e}");
        }
        let e = err(&(HEADER.to_owned() + "ATOM 1 N N . MET A 1 ? 1 2 3 1 9 1 A\n"));
        assert!(
            e.contains("t.cif:20:") && e.contains("16 value(s) of 17"),
            "{e}"
        );
        let e = err(&(HEADER.to_owned() + "ATOM 1 N N . MET A 1 ? 1 2 3 1 9 1 A 1\n;\nopen\n"));
        assert!(e.contains("t.cif:21:") && e.contains("text field"), "{e}");
        let e = err(
            &(HEADER.to_owned() + "ATOM 1 N N . MET A 1 ? 1 2 1 9 1 A 1\n")
                .replace("_atom_site.Cartn_z\n", ""),
        );
        assert!(e.contains("t.cif:2:") && e.contains("Cartn_z"), "{e}");
        let e = err(&(HEADER.to_owned() + "ATOMS 1 N N . MET A 1 ? 1 2 3 1 9 1 A 1\n"));
        assert!(e.contains("t.cif:20:") && e.contains("`ATOMS`"), "{e}");
        for empty in ["", "data_x\n_cell.length_a 5\n", HEADER] {
            assert!(err(empty).contains("no atoms"), "{empty:?}");
        }
        let waters = HEADER.to_owned() + "HETATM 1 O O . HOH A 1 ? 1 2 3 1 9 1 A 1\n";
        let e = err(&waters);
        assert!(e.contains("no atoms") && e.contains("HOH x1"), "{e}");
    }
}
