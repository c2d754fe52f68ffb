//! 4-connected components of a grid's cells: the box segmenter keeps its largest object
//! region with them, and the tracker picks a lost object's region among the pixels its
//! colours call object.

/// 4-connected components of the cells where `member` holds: each cell's component (None
/// outside) and each component's size.
pub fn components(w: usize, h: usize, member: impl Fn(usize) -> bool) -> (Vec<Option<usize>>, Vec<usize>) {
    let mut label = vec![None; w * h];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if label[start].is_some() || !member(start) {
            continue;
        }
        let c = sizes.len();
        sizes.push(0);
        label[start] = Some(c);
        stack.push(start);
        while let Some(i) = stack.pop() {
            sizes[c] += 1;
            let (x, y) = (i % w, i / w);
            let neighbours = [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)];
            for n in neighbours.into_iter().flatten() {
                if label[n].is_none() && member(n) {
                    label[n] = Some(c);
                    stack.push(n);
                }
            }
        }
    }
    (label, sizes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_and_sizes() {
        // 4×3 grid: an L of 4 cells and three lone cells, one touching the L only diagonally.
        //   X . . X
        //   X . X .
        //   X X . X
        let grid = [1, 0, 0, 1, 1, 0, 1, 0, 1, 1, 0, 1];
        let (labels, sizes) = components(4, 3, |i| grid[i] == 1);
        assert_eq!(sizes, vec![4, 1, 1, 1]);
        assert_eq!(labels[0], labels[9]);
        assert_ne!(labels[6], labels[9], "diagonal neighbours are apart");
        assert_eq!(labels[1], None);
        assert_eq!(components(0, 0, |_| true).1, Vec::<usize>::new());
    }
}
